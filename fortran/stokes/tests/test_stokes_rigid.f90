!> The exact-rigidity solve (fold_stokes_rigid) in its stencil form (3 + 3 transforms per
!> iteration: corner force scattered from the particles' voxels, strain gathered there)
!> and in its spectral form (5 + 5) is the same solve: on a sheared, non-cubic lattice
!> with a sphere of partial-volume boundary, serially and on two slabs, both reach the
!> tolerance, with the same iteration count within 10 % and the same particle stress and
!> velocity field to within the solve's own error. That error: each solution leaves a
!> residual r with ||r|| <= tol ||b||, so it differs from the exact one by at most
!> ||K^+|| tol ||b||, K the Schur operator; for this sphere the smallest non-zero
!> eigenvalue of K is above 1e-4 of its largest (the spectrum of a compact body; the
!> prototype in docs/physics.md#exact-rigidity measures 1e-4 for a slender fibre), so
!> the two differ by at most 2e4 tol relative to the particle stress.
!> Run with mpirun -np 1 or 2 (meson suite 'stokes').
program test_stokes_rigid
   use mpi_f08
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   use fold_settings, only: FOLD_RIGIDITY_EXACT
   use fold_stokes_rigid, only: stokes_rigid_t
   use stokes_test_check, only: check, ball_chi
   use stokes_test_solver, only: sheared_solver, mpi_test_start, mpi_test_end
   implicit none
   integer :: rank, failures
   real(dp) :: sig(3, 3, 2), vel(2), tol
   integer(ip) :: its(2)
   integer :: form

   call mpi_test_start("test_stokes_rigid", rank, failures)
   tol = 1.0e-11_dp
   do form = 1, 2
      call solve([14_ip, 12_ip, 10_ip], form == 1, tol, sig(:, :, form), vel(form), its(form), failures)
   end do
   if (rank == 0) print '(a,2(1x,i0),a,es10.3,a,es10.3)', "iterations stencil/spectral", its, &
      ", |d sigma_p| / |sigma_p| = ", norm2(sig(:, :, 1) - sig(:, :, 2))/norm2(sig(:, :, 2)), &
      ", |d u|^2 / |u|^2 = ", abs(vel(1) - vel(2))/vel(2)
   call check(abs(its(1) - its(2)) <= max(1, its(2)/10), "same iteration count within 10 %", failures)
   call check(norm2(sig(:, :, 1) - sig(:, :, 2)) <= 2.0e4_dp*tol*norm2(sig(:, :, 2)), &
              "same particle stress within the solve's error", failures)
   call check(abs(vel(1) - vel(2)) <= 2.0e4_dp*tol*vel(2), "same velocity field within the solve's error", &
              failures)
   call mpi_test_end(failures)

contains

   subroutine solve(n, stencil, tol, sigma_p, u2, iterations, failures)
      integer(ip), intent(in) :: n(3)
      logical, intent(in) :: stencil
      real(dp), intent(in) :: tol
      real(dp), intent(out) :: sigma_p(3, 3), u2
      integer(ip), intent(out) :: iterations
      integer, intent(inout) :: failures
      class(stokes_solver_t), allocatable :: s
      type(stokes_settings_t) :: set
      real(dp), allocatable :: chi(:, :, :)
      real(dp) :: G(3, 3), red(1)
      real(dp), pointer, contiguous :: f(:, :, :)
      integer :: stat, c
      character(len=msg_len) :: msg

      set%rigidity = FOLD_RIGIDITY_EXACT
      set%tol = tol
      set%max_iter = 5000
      set%warm_start = .false.
      call sheared_solver(set, n, s, failures)
      select type (s)
      type is (stokes_rigid_t)
         if (.not. stencil) s%stencil_fraction_max = -1.0_dp
         chi = ball_chi(n, s%grid%nl(2), s%grid%nl(3), s%grid%off(3), 0.45_dp)
         G = 0.0_dp
         G(1, 2) = 1.0_dp
         call s%solve(chi, G, stat, msg)
         call check(stat == FOLD_OK, "solve: "//trim(msg), failures)
         call check(s%stencil .eqv. stencil, "the form asked for", failures)
         call check(s%residual <= tol, "residual <= tol", failures)
         iterations = s%iterations
         sigma_p = s%multiplier_stress
         call s%compute_velocity()
         red = 0.0_dp
         do c = 1, 3
            f => s%velocity_field(int(c, ip))
            red(1) = red(1) + sum(f(1:n(1), :, :)**2)
         end do
         call s%sum_all(red)
         u2 = red(1)
      class default
         call check(.false., "factory did not give the exact-rigidity solver", failures)
      end select
      call s%destroy()
   end subroutine solve

end program test_stokes_rigid
