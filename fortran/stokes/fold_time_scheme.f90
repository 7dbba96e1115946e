!> Time schemes of the loops that march particles with velocities computed from the
!> flow (fold_stokes_step::stokes_march and the run driver's Stokes hydrodynamics,
!> fold_hydro_stokes), and the state they carry from step to step.
!>
!> The rigid velocities of a Stokes solve are combined in time by explicit Euler
!> (v_n) or Adams-Bashforth 2 (3/2 v_n - 1/2 v_(n-1); the first step, without a
!> history, is Euler); positions and orientations are then moved exactly
!> (fold_kinematics::rigid_update). The codes are those of /setup/resolved/time_scheme
!> and of pyfold/native/stokes.py SCHEMES.
!>
!> With solve re-use (a solve every k > 1 steps) the hydrodynamic velocity at a
!> step's time t is the linear extrapolation of the last two solves (times t_a > t_b):
!>     v(t) = v_a + ((t - t_a)/(t_a - t_b)) (v_a - v_b),
!> and the last solve itself at t = t_a, or while there is only one. With re-use by
!> departures (numerics.stokes.reuse = "jeffery") the solves stored are instead each
!> particle's departure from its dilute Jeffery velocity at the solved configuration,
!>     d = v_solve - v_J(x, p),
!> and the estimate at t is v_J(x(t), p(t)) + the same extrapolation of d: the rotation a
!> particle makes in the mean flow between solves (a tumbling fibre's angular velocity
!> changes by O(1) over a flip) is then followed every step, and only the interactions,
!> which change with the neighbours' relative positions, are extrapolated. At a solve's
!> own time both estimates are the solve. The AB2 history is that hydrodynamic velocity
!> (before contact corrections). Every stored velocity
!> crosses a sheared face of the Lees-Edwards cell with the particle, with the same
!> velocity jump (time_scheme_carry_across_wrap), so the combinations stay in one frame.
module fold_time_scheme
   use fold_kinds, only: dp, ip
   use fold_cell, only: cell_t, cell_wrap
   implicit none
   private

   !> Time-stepping schemes
   integer(ip), parameter, public :: FOLD_EULER = 1, FOLD_AB2 = 2

   !> AB2 history: the hydrodynamic velocities of the previous step.
   type, public :: scheme_history_t
      !> Translational (dim, n) [m/s] and angular (3, n) [1/s] velocity
      real(dp), allocatable :: v(:, :), omega(:, :)
      !> The history holds a step (else the next step is Euler)
      logical :: held = .false.
   end type scheme_history_t

   !> What the time scheme carries from step to step: the solves it combines and the
   !> AB2 history, with a saved copy of that history for the rollback to the last good
   !> state.
   type, public :: time_scheme_state_t
      !> FOLD_EULER or FOLD_AB2
      integer(ip) :: scheme = FOLD_EULER
      !> A solve every `solve_every` steps (> 1: the steps between extrapolate)
      integer(ip) :: solve_every = 1
      !> The stored solves are departures from the Jeffery velocity (re-use by departures)
      logical :: departures = .false.
      !> Velocities of the last solve and its time [s]
      real(dp), allocatable :: v_solve(:, :), omega_solve(:, :)
      real(dp) :: t_solve = 0.0_dp
      !> Velocities of the solve before it and its time [s] (solve re-use only)
      real(dp), allocatable :: v_solve_before(:, :), omega_solve_before(:, :)
      real(dp) :: t_solve_before = 0.0_dp
      !> A solve has been pushed; two have (the extrapolation has its two points)
      logical :: have_solve = .false., have_solve_before = .false.
      !> AB2 history, and its copy at the last good state
      type(scheme_history_t) :: history, good_history
   contains
      procedure :: init => time_scheme_init
      procedure :: push_solve => time_scheme_push_solve
      procedure :: step_velocity => time_scheme_step_velocity
      procedure :: carry_across_wrap => time_scheme_carry_across_wrap
      procedure :: keep_good => time_scheme_keep_good
      procedure :: restore_good => time_scheme_restore_good
   end type time_scheme_state_t

   public :: scheme_velocity

contains

   !> Velocity used over a step: v_now (Euler, or AB2 without history) or
   !> 1.5 v_now - 0.5 v_prev (AB2 with history). Same for omega.
   pure subroutine scheme_velocity(scheme, have_prev, v_now, v_prev, v)
      integer(ip), intent(in) :: scheme
      logical, intent(in) :: have_prev
      real(dp), intent(in) :: v_now(:, :), v_prev(:, :)
      real(dp), intent(out) :: v(:, :)
      if (scheme == FOLD_AB2 .and. have_prev) then
         v = 1.5_dp*v_now - 0.5_dp*v_prev
      else
         v = v_now
      end if
   end subroutine scheme_velocity

   !> Empty state for n particles in dim dimensions (no solve, no history); a state
   !> made before is emptied.
   subroutine time_scheme_init(self, scheme, solve_every, dim, n, departures)
      class(time_scheme_state_t), intent(inout) :: self
      !> FOLD_EULER or FOLD_AB2 (checked by the caller)
      integer(ip), intent(in) :: scheme
      !> A solve every solve_every (>= 1) steps
      integer(ip), intent(in) :: solve_every
      integer(ip), intent(in) :: dim, n
      !> The solves pushed are departures from the Jeffery velocity, and step_velocity gets
      !> the Jeffery velocity of the step (default: the solves are velocities)
      logical, intent(in), optional :: departures
      self%scheme = scheme
      self%solve_every = solve_every
      self%departures = .false.
      if (present(departures)) self%departures = departures
      if (allocated(self%v_solve)) deallocate (self%v_solve, self%omega_solve, self%v_solve_before, &
                                               self%omega_solve_before, self%history%v, self%history%omega)
      allocate (self%v_solve(dim, n), self%omega_solve(3, n))
      allocate (self%v_solve_before(dim, n), self%omega_solve_before(3, n))
      self%v_solve = 0.0_dp
      self%omega_solve = 0.0_dp
      self%v_solve_before = 0.0_dp
      self%omega_solve_before = 0.0_dp
      self%t_solve = 0.0_dp
      self%t_solve_before = 0.0_dp
      self%have_solve = .false.
      self%have_solve_before = .false.
      allocate (self%history%v(dim, n), self%history%omega(3, n))
      self%history%v = 0.0_dp
      self%history%omega = 0.0_dp
      self%history%held = .false.
      self%good_history = self%history
   end subroutine time_scheme_init

   !> The velocities of a new solve (with re-use by departures: their departures from the
   !> Jeffery velocity), of the configuration at time t [s]; with solve re-use the previous
   !> solve becomes the one before.
   subroutine time_scheme_push_solve(self, v, omega, t)
      class(time_scheme_state_t), intent(inout) :: self
      real(dp), intent(in) :: v(:, :), omega(:, :), t
      if (self%solve_every > 1 .and. self%have_solve) then
         self%v_solve_before = self%v_solve
         self%omega_solve_before = self%omega_solve
         self%t_solve_before = self%t_solve
         self%have_solve_before = .true.
      end if
      self%v_solve = v
      self%omega_solve = omega
      self%t_solve = t
      self%have_solve = .true.
   end subroutine time_scheme_push_solve

   !> The velocities (v, omega) of the step from t [s]: the hydrodynamic velocity at t
   !> (the last solve, or the extrapolation of the last two; with re-use by departures,
   !> the Jeffery velocity v_jeffery, omega_jeffery of the particles at t plus that of the
   !> departures) combined by the scheme with the history, which then becomes that
   !> hydrodynamic velocity.
   subroutine time_scheme_step_velocity(self, t, v, omega, v_jeffery, omega_jeffery)
      class(time_scheme_state_t), intent(inout) :: self
      real(dp), intent(in) :: t
      real(dp), intent(out) :: v(:, :), omega(:, :)
      !> Jeffery velocities (dim, n) and (3, n) of the particles at t (re-use by departures only)
      real(dp), intent(in), optional :: v_jeffery(:, :), omega_jeffery(:, :)
      real(dp), allocatable :: v_est(:, :), omega_est(:, :)

      if (self%solve_every > 1 .and. self%have_solve_before .and. t > self%t_solve) then
         v_est = self%v_solve + ((t - self%t_solve)/(self%t_solve - self%t_solve_before))* &
                 (self%v_solve - self%v_solve_before)
         omega_est = self%omega_solve + ((t - self%t_solve)/(self%t_solve - self%t_solve_before))* &
                     (self%omega_solve - self%omega_solve_before)
      else
         v_est = self%v_solve
         omega_est = self%omega_solve
      end if
      if (self%departures) then
         v_est = v_est + v_jeffery
         omega_est = omega_est + omega_jeffery
      end if
      call scheme_velocity(self%scheme, self%history%held, v_est, self%history%v, v)
      call scheme_velocity(self%scheme, self%history%held, omega_est, self%history%omega, omega)
      call move_alloc(v_est, self%history%v)
      call move_alloc(omega_est, self%history%omega)
      self%history%held = .true.
   end subroutine time_scheme_step_velocity

   !> After the particles at x_before (dim, n) [m] were wrapped into the cell: give the
   !> stored translational velocities of each particle the same Lees-Edwards jump (the
   !> history; with solve re-use also the two solves, unless they are departures from the
   !> Jeffery velocity, which carries the jump itself).
   subroutine time_scheme_carry_across_wrap(self, cell, x_before)
      class(time_scheme_state_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: x_before(:, :)
      real(dp) :: xk(3)
      integer :: k, d

      d = size(x_before, 1)
      do k = 1, size(x_before, 2)
         xk(1:d) = x_before(:, k)
         call cell_wrap(cell, xk(1:d), self%history%v(:, k))
         if (self%solve_every > 1 .and. .not. self%departures) then
            xk(1:d) = x_before(:, k)
            call cell_wrap(cell, xk(1:d), self%v_solve(:, k))
            xk(1:d) = x_before(:, k)
            call cell_wrap(cell, xk(1:d), self%v_solve_before(:, k))
         end if
      end do
   end subroutine time_scheme_carry_across_wrap

   !> The current configuration is good: keep a copy of the history for a rollback.
   subroutine time_scheme_keep_good(self)
      class(time_scheme_state_t), intent(inout) :: self
      self%good_history = self%history
   end subroutine time_scheme_keep_good

   !> Back to the history of the last good state (the failing step is dropped).
   subroutine time_scheme_restore_good(self)
      class(time_scheme_state_t), intent(inout) :: self
      self%history = self%good_history
   end subroutine time_scheme_restore_good

end module fold_time_scheme
