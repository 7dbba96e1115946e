!> fold_time_scheme's state object against the formulas of its module header, to the bit:
!> * Euler on the first step, then Adams-Bashforth 2: 1.5 v_n - 0.5 v_(n-1);
!> * solve re-use: between solves, the linear extrapolation of the last two, and the
!>   history is that extrapolated velocity;
!> * re-use by departures: the estimate is the Jeffery velocity given plus the linear
!>   extrapolation of the pushed departures, and the departures do not jump across a
!>   sheared face (the Jeffery velocity does);
!> * keep_good / restore_good return the history of the kept state;
!> * a particle crossing the sheared face (Lees-Edwards) carries the history across with
!>   the velocity jump -G_xy Ly, the same jump as its own velocity.
program test_time_scheme
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_init, cell_set_time, cell_wrap
   use fold_time_scheme, only: time_scheme_state_t, FOLD_EULER, FOLD_AB2
   implicit none
   integer :: failures = 0

   call ab2_after_euler(failures)
   call reuse_extrapolates(failures)
   call reuse_by_departures(failures)
   call rollback(failures)
   call history_crosses_sheared_face(failures)
   if (failures /= 0) error stop "test_time_scheme: a check failed (FAILED lines above)"
   print '(a)', "test_time_scheme: all checks passed"

contains

   !> Count and name a failed check.
   subroutine check(ok, what, failures)
      logical, intent(in) :: ok
      character(len=*), intent(in) :: what
      integer, intent(inout) :: failures
      if (ok) return
      failures = failures + 1
      print '(2a)', "FAILED: ", what
   end subroutine check

   !> A 4 x 3 Lees-Edwards cell in simple shear G_xy = 2 at t = 0.1: a particle above y = 3
   !> wraps through the sheared face with the velocity jump -G_xy Ly = -6.
   subroutine sheared_cell(cell, failures)
      type(cell_t), intent(out) :: cell
      integer, intent(inout) :: failures
      real(dp) :: G(3, 3)
      integer :: stat
      character(len=msg_len) :: errmsg
      G = 0.0_dp
      G(1, 2) = 2.0_dp
      call cell_init(cell, 2_ip, [4.0_dp, 3.0_dp, 1.0_dp], .false., G, stat, errmsg)
      call check(stat == FOLD_OK, "cell_init: "//trim(errmsg), failures)
      call cell_set_time(cell, 0.1_dp)
   end subroutine sheared_cell

   subroutine ab2_after_euler(failures)
      integer, intent(inout) :: failures
      type(time_scheme_state_t) :: s
      real(dp) :: v1(2, 2), w1(3, 2), v2(2, 2), w2(3, 2), v(2, 2), w(3, 2)
      v1 = reshape([0.3_dp, -0.7_dp, 1.1_dp, 0.2_dp], [2, 2])
      w1 = 0.1_dp
      v2 = reshape([0.35_dp, -0.6_dp, 1.0_dp, 0.25_dp], [2, 2])
      w2 = 0.13_dp
      call s%init(FOLD_AB2, 1_ip, 2_ip, 2_ip)
      call s%push_solve(v1, w1, 0.0_dp)
      call s%step_velocity(0.0_dp, v, w)
      call check(all(v == v1) .and. all(w == w1), "first step is Euler", failures)
      call s%push_solve(v2, w2, 0.1_dp)
      call s%step_velocity(0.1_dp, v, w)
      call check(all(v == 1.5_dp*v2 - 0.5_dp*v1) .and. all(w == 1.5_dp*w2 - 0.5_dp*w1), &
                 "second step is 1.5 v_n - 0.5 v_(n-1)", failures)
      call s%init(FOLD_EULER, 1_ip, 2_ip, 2_ip)
      call s%push_solve(v1, w1, 0.0_dp)
      call s%step_velocity(0.0_dp, v, w)
      call s%push_solve(v2, w2, 0.1_dp)
      call s%step_velocity(0.1_dp, v, w)
      call check(all(v == v2) .and. all(w == w2), "Euler uses the last solve", failures)
   end subroutine ab2_after_euler

   subroutine reuse_extrapolates(failures)
      integer, intent(inout) :: failures
      type(time_scheme_state_t) :: s
      real(dp) :: va(2, 1), wa(3, 1), vb(2, 1), wb(3, 1), v(2, 1), w(3, 1), v_est(2, 1)
      va(:, 1) = [1.0_dp, 2.0_dp]
      wa = 0.5_dp
      vb(:, 1) = [1.5_dp, 1.0_dp]
      wb = 0.25_dp
      call s%init(FOLD_AB2, 2_ip, 2_ip, 1_ip)
      call s%push_solve(va, wa, 0.0_dp)
      call s%push_solve(vb, wb, 0.2_dp)
      call s%step_velocity(0.2_dp, v, w)
      call check(all(v == vb), "at the last solve's time: that solve", failures)
      call s%step_velocity(0.3_dp, v, w)
      v_est = vb + ((0.3_dp - 0.2_dp)/(0.2_dp - 0.0_dp))*(vb - va)
      call check(all(v == 1.5_dp*v_est - 0.5_dp*vb), "between solves: AB2 of the extrapolation", failures)
      call check(all(s%history%v == v_est), "the history is the extrapolated velocity", failures)
   end subroutine reuse_extrapolates

   subroutine reuse_by_departures(failures)
      integer, intent(inout) :: failures
      type(time_scheme_state_t) :: s
      type(cell_t) :: cell
      real(dp) :: da(2, 1), wa(3, 1), db(2, 1), wb(3, 1), vj(2, 1), wj(3, 1), v(2, 1), w(3, 1)
      real(dp) :: d_est(2, 1), w_est(3, 1), x(2, 1), x_before(2, 1)
      da(:, 1) = [0.1_dp, -0.2_dp]
      wa = 0.05_dp
      db(:, 1) = [0.15_dp, -0.1_dp]
      wb = 0.02_dp
      vj(:, 1) = [3.0_dp, 0.0_dp]
      wj = -0.5_dp
      call s%init(FOLD_AB2, 4_ip, 2_ip, 1_ip, departures=.true.)
      call s%push_solve(da, wa, 0.0_dp)
      call s%push_solve(db, wb, 0.4_dp)
      call s%step_velocity(0.4_dp, v, w, vj, wj)
      call check(all(v == vj + db) .and. all(w == wj + wb), "at the last solve's time: Jeffery + its departure", &
                 failures)
      call s%step_velocity(0.5_dp, v, w, 2.0_dp*vj, 2.0_dp*wj)
      d_est = db + ((0.5_dp - 0.4_dp)/(0.4_dp - 0.0_dp))*(db - da)
      w_est = wb + ((0.5_dp - 0.4_dp)/(0.4_dp - 0.0_dp))*(wb - wa)
      call check(all(s%history%v == 2.0_dp*vj + d_est) .and. all(s%history%omega == 2.0_dp*wj + w_est), &
                 "between solves: the Jeffery velocity of the step + the extrapolated departure", failures)
      call check(all(v == 1.5_dp*(2.0_dp*vj + d_est) - 0.5_dp*(vj + db)), "combined by AB2", failures)
      ! across the sheared face only the history jumps; the departures are periodic
      call sheared_cell(cell, failures)
      x(:, 1) = [1.0_dp, 3.2_dp]
      x_before = x
      call cell_wrap(cell, x(:, 1), v(:, 1))
      call s%carry_across_wrap(cell, x_before)
      call check(all(s%v_solve == db) .and. all(s%v_solve_before == da), "departures do not jump", failures)
      call check(s%history%v(1, 1) == 2.0_dp*vj(1, 1) + d_est(1, 1) - 6.0_dp, "the history jumps by -G_xy Ly", &
                 failures)
   end subroutine reuse_by_departures

   subroutine rollback(failures)
      integer, intent(inout) :: failures
      type(time_scheme_state_t) :: s
      real(dp) :: v1(2, 1), w1(3, 1), v(2, 1), w(3, 1)
      v1(:, 1) = [1.0_dp, -1.0_dp]
      w1 = 2.0_dp
      call s%init(FOLD_AB2, 1_ip, 2_ip, 1_ip)
      call s%keep_good()
      call s%push_solve(v1, w1, 0.0_dp)
      call s%step_velocity(0.0_dp, v, w)
      call check(s%history%held, "a step fills the history", failures)
      call s%restore_good()
      call check(.not. s%history%held .and. all(s%history%v == 0.0_dp), "restore returns the kept history", &
                 failures)
   end subroutine rollback

   subroutine history_crosses_sheared_face(failures)
      integer, intent(inout) :: failures
      type(time_scheme_state_t) :: s
      type(cell_t) :: cell
      real(dp) :: x(2, 1), x_before(2, 1), v(2, 1), w(3, 1), vs(2, 1), ws(3, 1)
      call sheared_cell(cell, failures)
      vs(:, 1) = [0.5_dp, 0.1_dp]
      ws = 0.0_dp
      call s%init(FOLD_AB2, 1_ip, 2_ip, 1_ip)
      call s%push_solve(vs, ws, 0.0_dp)
      call s%step_velocity(0.0_dp, v, w)
      x(:, 1) = [1.0_dp, 3.2_dp]  ! above Ly = 3: wraps through the sheared face
      x_before = x
      call cell_wrap(cell, x(:, 1), v(:, 1))
      call s%carry_across_wrap(cell, x_before)
      call check(s%history%v(1, 1) == vs(1, 1) - 2.0_dp*3.0_dp .and. s%history%v(2, 1) == vs(2, 1), &
                 "history jumps by -G_xy Ly", failures)
      call check(all(s%history%v == v), "history jumps as the particle's velocity", failures)
   end subroutine history_crosses_sheared_face

end program test_time_scheme
