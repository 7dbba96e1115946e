!> Stokes hydrodynamics (/setup/resolved/hydrodynamics = 1): the rigid (V, omega) of
!> every particle from the fictitious-domain Stokes solve of the configuration, with
!> the sphere lubrication correction when /setup/resolved/lubrication is on
!> (fold_stokes_step::stokes_rigid_velocities, fold_lubrication), by the one solver
!> fold_stokes_factory makes from /setup/resolved/stokes_* (for the fft backend the
!> grid is distributed over the ranks with FFTW-MPI when np > 1). A cell with walls
!> (Couette) gives its walls to the solver settings and the backend imposes them.
!>
!> The solves are combined in time by fold_time_scheme (explicit Euler or
!> Adams-Bashforth 2; with solve re-use, stokes_solve_every = k > 1, a solve every
!> k-th step and the linear extrapolation of the last two between; with
!> stokes_reuse = FOLD_REUSE_JEFFERY the extrapolation is of each particle's departure from
!> its dilute Jeffery velocity, fold_kinematics::jeffery_omega and the cell's mean flow,
!> which is added back at the step's own state). The solve of the
!> configuration at t + dt is made at the end of the step, so every record holds the
!> bulk stress of the configuration at its own time. A solve whose stress is not
!> trusted (fold_stokes_trust: an effective viscosity below the fluid's) puts nothing
!> into the record.
module fold_hydro_stokes
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use mpi_f08, only: MPI_COMM_WORLD
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_NUMERICAL, FOLD_NOT_CONVERGED
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t, cell_mean_velocity
   use fold_kinematics, only: jeffery_omega
   use fold_run_file, only: run_setup_t
   use fold_output, only: run_record_t
   use fold_time_scheme, only: FOLD_AB2
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, stokes_backend_name
   use fold_settings, only: FOLD_RIGIDITY_NAME, FOLD_RIGIDITY_USES_KAPPA, FOLD_REUSE_JEFFERY
   use fold_stokes_factory, only: stokes_solver_create
   use fold_stokes_step, only: stokes_context_t, stokes_record_t, stokes_context_attach, stokes_context_destroy, &
                               stokes_rigid_velocities, stokes_context_lubrication
   use fold_stokes_trust, only: stokes_kappa_check, stokes_stress_check
   use fold_hydro, only: hydro_model_t
   implicit none
   private

   public :: stokes_init

   !> Fictitious-domain Stokes hydrodynamics.
   type, extends(hydro_model_t), public :: hydro_stokes_t
      type(stokes_context_t) :: ctx
      !> Settings of the solver (with the cell's walls)
      type(stokes_settings_t) :: set
      !> Grid points of the solver
      integer(i8) :: grid_points = 0
      !> A solve after every `solve_every`-th step
      integer(i8) :: solve_every = 1
   contains
      procedure :: velocities => stokes_velocities
      procedure :: carry_across_wrap => stokes_carry_across_wrap
      procedure :: solve_due => stokes_solve_due
      procedure :: solve_configuration => stokes_solve_configuration
      procedure :: destroy => stokes_destroy
   end type hydro_stokes_t

contains

   !> The solver (fold_stokes_factory, on MPI_COMM_WORLD) from the settings of
   !> /setup/resolved, an empty time-scheme state; rank 0 prints the solver line.
   subroutine stokes_init(self, setup, parts, rank, nranks, stat, errmsg)
      type(hydro_stokes_t), intent(inout) :: self
      type(run_setup_t), intent(in) :: setup
      type(particle_set_t), intent(in) :: parts
      integer, intent(in) :: rank, nranks
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      class(stokes_solver_t), allocatable :: solver
      integer :: envstat

      self%solves_flow = .true.
      self%residual = ieee_value(1.0_dp, ieee_quiet_nan)
      self%grid_points = product(int(setup%stokes_grid, i8))
      self%solve_every = int(setup%stokes_solve_every, i8)
      ! walls are a property of the cell (fold_cell): the backend imposes them when set
      self%set = setup%stokes
      self%set%walls = setup%walls
      ! the kappa the solver can carry at this grid, tolerance and precision
      ! (fold_stokes_trust); FOLD_RUN_UNCHECKED_KAPPA set in the environment waives it, for
      ! the test of the run-time stress check only (tests/micro/test_stokes_trust.py)
      call get_environment_variable("FOLD_RUN_UNCHECKED_KAPPA", status=envstat)
      if (envstat /= 0 .and. FOLD_RIGIDITY_USES_KAPPA(self%set%rigidity)) then
         call stokes_kappa_check(self%set, self%grid_points, stat, errmsg)
         if (stat /= FOLD_OK) then
            errmsg = "/setup/resolved/stokes_kappa: "//trim(errmsg)
            return
         end if
      end if
      call stokes_solver_create(self%set, setup%dim, setup%stokes_grid, MPI_COMM_WORLD, solver, stat, errmsg)
      if (stat /= FOLD_OK) then
         errmsg = "/setup/resolved/stokes_*: "//trim(errmsg)
         return
      end if
      call stokes_context_attach(self%ctx, solver)
      call stokes_context_lubrication(self%ctx, setup%lubrication, setup%alpha)
      call self%scheme%init(setup%time_scheme, setup%stokes_solve_every, parts%dim, parts%n, &
                            departures=setup%stokes_solve_every > 1 .and. setup%stokes_reuse == FOLD_REUSE_JEFFERY)
      if (rank == 0) call announce(setup, parts%dim, nranks)
   end subroutine stokes_init

   !> The solver line of stdout: grid, backend, ranks, rigidity, tolerance, time scheme.
   subroutine announce(setup, dim, nranks)
      type(run_setup_t), intent(in) :: setup
      integer(ip), intent(in) :: dim
      integer, intent(in) :: nranks
      character(len=msg_len) :: grid

      ! one "x" between counts: a format with more descriptors than counts would end in "x"
      if (dim == 2) then
         write (grid, '(i0,"x",i0)') setup%stokes_grid(1:2)
      else
         write (grid, '(i0,"x",i0,"x",i0)') setup%stokes_grid(1:3)
      end if
      grid = trim(grid)//" ("//stokes_backend_name(setup%stokes%backend)//")"
      if (.not. FOLD_RIGIDITY_USES_KAPPA(setup%stokes%rigidity)) then
         write (output_unit, '(a,a,a,i0,a,a,a,es9.2,a,a)') "fold_run: Stokes grid ", trim(grid), " on ", nranks, &
            " rank(s), ", trim(FOLD_RIGIDITY_NAME(setup%stokes%rigidity)), " rigidity, tol ", setup%stokes%tol, ", ", &
            trim(merge("Adams-Bashforth 2", "explicit Euler   ", setup%time_scheme == FOLD_AB2))
      else
         write (output_unit, '(a,a,a,i0,a,es9.2,a,es9.2,a,a)') "fold_run: Stokes grid ", trim(grid), " on ", &
            nranks, " rank(s), kappa ", setup%stokes%kappa, ", tol ", setup%stokes%tol, ", ", &
            trim(merge("Adams-Bashforth 2", "explicit Euler   ", setup%time_scheme == FOLD_AB2))
      end if
      if (setup%stokes_solve_every > 1) write (output_unit, '(a,i0,a,a)') "fold_run: a Stokes solve every ", &
         setup%stokes_solve_every, " steps, between them ", trim(merge("Jeffery + extrapolated departures", &
                                                                       "the solves extrapolated          ", &
                                                                       setup%stokes_reuse == FOLD_REUSE_JEFFERY))
      if (setup%stokes%fibre_radius_scale /= 1.0_dp) write (output_unit, '(a,f6.3,a)') &
         "fold_run: fibres voxelised at ", setup%stokes%fibre_radius_scale, &
         " times their radius (contacts keep the geometric radius)"
   end subroutine announce

   !> The time scheme's velocity of the step from t (every rank computes all particles).
   subroutine stokes_velocities(self, cell, parts, t, first, last)
      class(hydro_stokes_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      real(dp), intent(in) :: t
      integer(ip), intent(in) :: first, last
      real(dp), allocatable :: v_jeffery(:, :), omega_jeffery(:, :)
      if (self%scheme%departures) then
         call dilute_velocities(cell, parts, v_jeffery, omega_jeffery)
         call self%scheme%step_velocity(t, parts%v, parts%omega, v_jeffery, omega_jeffery)
      else
         call self%scheme%step_velocity(t, parts%v, parts%omega)
      end if
   end subroutine stokes_velocities

   !> Dilute Jeffery velocities of every particle at its current state: the cell's mean
   !> flow at its centre and Jeffery's angular velocity of its axis with its own xi
   !> (vorticity/2 for xi = 0), the reference that re-use by departures adds back.
   pure subroutine dilute_velocities(cell, parts, v, omega)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      real(dp), allocatable, intent(out) :: v(:, :), omega(:, :)
      integer(ip) :: k
      allocate (v(parts%dim, parts%n), omega(3, parts%n))
      do k = 1, parts%n
         v(:, k) = cell_mean_velocity(cell, parts%x(:, k))
         omega(:, k) = jeffery_omega(parts%dim, cell%G, parts%p(:, k), parts%xi(k))
      end do
   end subroutine dilute_velocities

   !> The AB2 history (and the re-used solves) cross a sheared face with the same
   !> velocity jump as the particle.
   subroutine stokes_carry_across_wrap(self, cell, x_before)
      class(hydro_stokes_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: x_before(:, :)
      call self%scheme%carry_across_wrap(cell, x_before)
   end subroutine stokes_carry_across_wrap

   logical function stokes_solve_due(self, step)
      class(hydro_stokes_t), intent(in) :: self
      integer(i8), intent(in) :: step
      stokes_solve_due = mod(step, self%solve_every) == 0
   end function stokes_solve_due

   !> Stokes solve of the configuration (all ranks): its rigid velocities go to the
   !> time scheme, its solver statistics and stress into rec; parts%v, parts%omega are
   !> left as they were.
   subroutine stokes_solve_configuration(self, cell, parts, t, rec, stat, errmsg, untrusted)
      class(hydro_stokes_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      real(dp), intent(in) :: t
      type(run_record_t), intent(inout) :: rec
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      logical, intent(out) :: untrusted
      type(stokes_record_t) :: srec
      real(dp), allocatable :: v_step(:, :), omega_step(:, :), v_jeffery(:, :), omega_jeffery(:, :)

      v_step = parts%v
      omega_step = parts%omega
      call stokes_rigid_velocities(self%ctx, cell, parts, srec, stat, errmsg)
      if (self%scheme%departures) then
         call dilute_velocities(cell, parts, v_jeffery, omega_jeffery)
         call self%scheme%push_solve(parts%v - v_jeffery, parts%omega - omega_jeffery, t)
      else
         call self%scheme%push_solve(parts%v, parts%omega, t)
      end if
      parts%v = v_step
      parts%omega = omega_step
      untrusted = .false.
      if (stat == FOLD_OK) then
         call stokes_stress_check(srec%bulk%eta_eff, self%set%eta_f, self%grid_points, self%set%kappa, &
                                  self%set%tol, stat, errmsg)
         untrusted = stat /= FOLD_OK
         if (untrusted) then
            ! no number of this solve goes into a record
            errmsg = "Stokes solve: "//trim(errmsg)
            return
         end if
      end if
      if (stat == FOLD_OK .or. stat == FOLD_NOT_CONVERGED) then
         self%cg_iterations = self%cg_iterations + srec%iterations
         self%residual = srec%residual
         rec%stokes_iterations = max(rec%stokes_iterations, int(srec%iterations, i8))
         rec%stokes_residual = max(rec%stokes_residual, srec%residual)
         rec%rigidity_max = max(rec%rigidity_max, srec%rigidity_max)
         rec%rigidity_mean = max(rec%rigidity_mean, srec%rigidity_mean)
         rec%stress = srec%bulk%sigma(1:parts%dim, 1:parts%dim)
         rec%effective_viscosity = srec%bulk%eta_eff
         rec%lubricated_pairs = max(rec%lubricated_pairs, int(srec%lub%pairs, i8))
         rec%lubrication_correction = max(rec%lubrication_correction, srec%lub%max_correction)
      end if
      if (stat == FOLD_OK) then
         if (.not. (all(abs(self%scheme%v_solve) <= huge(1.0_dp)) .and. &
                    all(abs(self%scheme%omega_solve) <= huge(1.0_dp)))) then
            stat = FOLD_NUMERICAL
            errmsg = "Stokes solve gave NaN or infinite particle velocities"
         end if
      else
         errmsg = "Stokes solver: "//trim(errmsg)
      end if
   end subroutine stokes_solve_configuration

   subroutine stokes_destroy(self)
      class(hydro_stokes_t), intent(inout) :: self
      call stokes_context_destroy(self%ctx)
   end subroutine stokes_destroy

end module fold_hydro_stokes
