!> Driver-level Stokes step: particles -> chi -> flow -> rigid (v, omega) + records.
!>
!> The run driver holds one stokes_context_t (plans and storage made once) and
!> calls stokes_rigid_velocities every step with the current cell (its
!> Lees-Edwards offset gives the lattice) and particle set; v and omega of the
!> set are overwritten with the rigid motion fitted to the computed flow
!> (contacts are resolved afterwards, as for the Jeffery kinematics). With
!> lubrication on (stokes_context_lubrication) the fitted sphere velocities then get
!> the lubrication correction of fold_lubrication: threshold h_c = 2 voxel widths of
!> the solver's grid, floor max(alpha, 1e-3 h_c), the fluid viscosity of the settings
!> (docs/physics.md#lubrication-between-spheres). The per-step record holds what
!> docs/physics.md#what-to-record-every-step lists, plus the lubricated pairs.
!> stokes_march integrates a set in time (fold_time_scheme: explicit Euler or Adams-Bashforth 2,
!> exact rotations) for tests and studies, through the same time-scheme state
!> (time_scheme_state_t) as the run driver's Stokes hydrodynamics (fold_hydro_stokes).
module fold_stokes_step
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NOT_CONVERGED
   use fold_cell, only: cell_t, cell_set_time, cell_wrap
   use fold_particles, only: particle_set_t, particles_check, FOLD_SPHERE
   use fold_kinematics, only: rigid_update
   use fold_grid, only: shear_lattice
   use fold_voxelise, only: voxel_set_t, voxelise
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   use fold_settings, only: FOLD_SHELLS_APART
   use fold_stokes_build, only: stokes_serial_create
   use fold_time_scheme, only: FOLD_EULER, FOLD_AB2, time_scheme_state_t
   use fold_rigid_fit, only: rigid_fit
   use fold_stress, only: bulk_stress_t, bulk_stress
   use fold_lubrication, only: lubrication_stats_t, lubrication_correct, lubrication_threshold, &
                               lubrication_gap_floor
   implicit none
   private

   ! the time-scheme codes, re-exported for callers of stokes_march
   public :: FOLD_EULER, FOLD_AB2

   !> What one Stokes step reports (recorded every step).
   type, public :: stokes_record_t
      !> CG iterations and relative preconditioned residual reached
      integer(ip) :: iterations = 0
      real(dp) :: residual = 0.0_dp
      !> Relative preconditioned residual of the initial guess [-]
      real(dp) :: residual0 = 0.0_dp
      logical :: converged = .false.
      !> Largest and mean rigidity residual of the particles [-]
      real(dp) :: rigidity_max = 0.0_dp, rigidity_mean = 0.0_dp
      !> Bulk stress, effective viscosity, solid strain ratio, solid fraction
      type(bulk_stress_t) :: bulk
      !> Lubrication correction (pairs, iterations, largest |delta v|; zero when off)
      type(lubrication_stats_t) :: lub
   end type stokes_record_t

   !> Solver + voxel storage kept across steps.
   type, public :: stokes_context_t
      class(stokes_solver_t), allocatable :: solver
      type(voxel_set_t) :: vox
      !> Rigidity residual of each particle after the last step [-]
      real(dp), allocatable :: rigidity(:)
      !> Sphere lubrication on, and the security zone alpha its gap floor uses [m] (also the
      !> gap the added fibre shells keep with fibre_shells apart)
      logical :: lubrication = .false.
      real(dp) :: alpha = 0.0_dp
   end type stokes_context_t

   public :: stokes_context_init, stokes_context_attach, stokes_context_destroy, stokes_rigid_velocities, stokes_march
   public :: stokes_context_lubrication

contains

   !> Make the solver of the settings on a grid of n voxels in this process and
   !> allocate once (fold_stokes_build::stokes_serial_create, the construction that
   !> fold_stokes_factory uses on one rank; over MPI ranks the factory's solver is
   !> taken over by stokes_context_attach).
   subroutine stokes_context_init(ctx, set, dim, n, stat, errmsg)
      type(stokes_context_t), intent(inout) :: ctx
      type(stokes_settings_t), intent(in) :: set
      !> Spatial dimension (2 or 3) and voxel counts (n(3) = 1 in 2-D)
      integer(ip), intent(in) :: dim, n(3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call stokes_context_destroy(ctx)
      call stokes_serial_create(set, dim, n, ctx%solver, stat, errmsg)
   end subroutine stokes_context_init

   !> Take over a solver made by the factory.
   subroutine stokes_context_attach(ctx, solver)
      type(stokes_context_t), intent(inout) :: ctx
      class(stokes_solver_t), allocatable, intent(inout) :: solver
      call stokes_context_destroy(ctx)
      call move_alloc(solver, ctx%solver)
   end subroutine stokes_context_attach

   !> Switch the sphere lubrication correction on or off; alpha (>= 0) is the security
   !> zone of the contacts, the floor of the lubrication gap [m].
   subroutine stokes_context_lubrication(ctx, on, alpha)
      type(stokes_context_t), intent(inout) :: ctx
      logical, intent(in) :: on
      real(dp), intent(in) :: alpha
      ctx%lubrication = on
      ctx%alpha = alpha
   end subroutine stokes_context_lubrication

   subroutine stokes_context_destroy(ctx)
      type(stokes_context_t), intent(inout) :: ctx
      if (allocated(ctx%solver)) then
         call ctx%solver%destroy()
         deallocate (ctx%solver)
      end if
      if (allocated(ctx%rigidity)) deallocate (ctx%rigidity)
   end subroutine stokes_context_destroy

   !> Rigid velocities of every particle from the fictitious-domain Stokes flow.
   !> On FOLD_NOT_CONVERGED v/omega/rec are still filled from the last iterate
   !> (the driver decides: halve the step or stop).
   subroutine stokes_rigid_velocities(ctx, cell, parts, rec, stat, errmsg)
      type(stokes_context_t), intent(inout) :: ctx
      !> Periodic cell with its current Lees-Edwards offset, or a Couette cell with
      !> walls (then the solver must have been made for walls, set%walls)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      type(stokes_record_t), intent(out) :: rec
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: solve_stat, st
      character(len=msg_len) :: solve_msg

      if (.not. allocated(ctx%solver)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "stokes_rigid_velocities: the context has no solver (stokes_context_init first)"
         return
      end if
      if (cell%walls .neqv. ctx%solver%set%walls) then
         stat = FOLD_INPUT_ERROR
         if (cell%walls) then
            errmsg = "stokes_rigid_velocities: the cell has walls but the solver was made for a periodic cell "// &
                     "(settings walls = false)"
         else
            errmsg = "stokes_rigid_velocities: the solver was made for walls (settings walls = true) but the cell "// &
                     "is periodic"
         end if
         return
      end if
      if (cell%dim /= ctx%solver%dim .or. parts%dim /= ctx%solver%dim) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a,i0,a,i0)') "stokes_rigid_velocities: dimensions differ: solver ", ctx%solver%dim, &
            ", cell ", cell%dim, ", particles ", parts%dim
         return
      end if
      call particles_check(parts, stat, errmsg)
      if (stat /= FOLD_OK) return
      call ctx%solver%set_lattice(shear_lattice(cell%lengths, cell%shear_offset), stat, errmsg)
      if (stat /= FOLD_OK) return
      ! the shells of a calibrated radius kept alpha apart, or overlapping (a negative gap)
      call voxelise(ctx%solver%grid, parts, ctx%solver%set%subsamples, ctx%solver%set%fibre_ends, ctx%vox, &
                    stat, errmsg, walls=cell%walls, fibre_radius_scale=ctx%solver%set%fibre_radius_scale, &
                    shell_gap=merge(ctx%alpha, -1.0_dp, ctx%solver%set%fibre_shells == FOLD_SHELLS_APART))
      if (stat /= FOLD_OK) return
      call ctx%solver%solve(ctx%vox%chi, cell%G, solve_stat, solve_msg)
      if (solve_stat /= FOLD_OK .and. solve_stat /= FOLD_NOT_CONVERGED) then
         stat = solve_stat
         errmsg = solve_msg
         return
      end if
      rec%iterations = ctx%solver%iterations
      rec%residual = ctx%solver%residual
      rec%residual0 = ctx%solver%history(0)
      rec%converged = solve_stat == FOLD_OK
      call ctx%solver%compute_velocity()
      if (allocated(ctx%rigidity)) then
         if (size(ctx%rigidity) /= parts%n) deallocate (ctx%rigidity)
      end if
      if (.not. allocated(ctx%rigidity)) allocate (ctx%rigidity(parts%n))
      call rigid_fit(ctx%solver, cell, ctx%vox, parts, ctx%rigidity, st, errmsg)
      if (st /= FOLD_OK) then
         stat = st
         return
      end if
      if (parts%n > 0) then
         rec%rigidity_max = maxval(ctx%rigidity)
         rec%rigidity_mean = sum(ctx%rigidity)/parts%n
      end if
      if (ctx%lubrication) then
         call lubricate(st, errmsg)
         if (st /= FOLD_OK) then
            stat = st
            return
         end if
      end if
      call bulk_stress(ctx%solver, ctx%vox%chi, rec%bulk, st, errmsg)
      if (st /= FOLD_OK) then
         stat = st
         return
      end if
      stat = solve_stat
      errmsg = solve_msg

   contains

      !> parts%v += the lubrication correction of the fitted velocities (every rank
      !> holds the same particles and fitted velocities, so each computes the same).
      subroutine lubricate(lstat, lmsg)
         integer, intent(out) :: lstat
         character(len=msg_len), intent(out) :: lmsg
         real(dp), allocatable :: dv(:, :)
         real(dp) :: h_c
         allocate (dv(parts%dim, parts%n))
         h_c = lubrication_threshold(ctx%solver%grid%h)
         call lubrication_correct(cell, parts%x, parts%radius, parts%shape == FOLD_SPHERE, parts%v, &
                                  ctx%solver%set%eta_f, h_c, lubrication_gap_floor(ctx%alpha, h_c), dv, rec%lub, &
                                  lstat, lmsg)
         if (lstat /= FOLD_OK) return
         parts%v = parts%v + dv
      end subroutine lubricate
   end subroutine stokes_rigid_velocities

   !> Integrate parts over nsteps steps of dt from time t0 with the Stokes rigid
   !> velocities: Euler (first order) or Adams-Bashforth 2 (second order; first
   !> step Euler) on v and omega, with exact rotations (rigid_update) and the
   !> Lees-Edwards wrap (the stored previous velocity gets the same jump).
   !> Histories: x_hist/p_hist(dim, n, 0:nsteps), records recs(1:nsteps).
   subroutine stokes_march(ctx, cell, parts, t0, dt, nsteps, scheme, x_hist, p_hist, recs, stat, errmsg)
      type(stokes_context_t), intent(inout) :: ctx
      type(cell_t), intent(inout) :: cell
      type(particle_set_t), intent(inout) :: parts
      !> Start time (sets the Lees-Edwards offset) and step [s]
      real(dp), intent(in) :: t0, dt
      integer(ip), intent(in) :: nsteps
      !> FOLD_EULER or FOLD_AB2
      integer(ip), intent(in) :: scheme
      real(dp), intent(out) :: x_hist(:, :, 0:), p_hist(:, :, 0:)
      type(stokes_record_t), intent(out) :: recs(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(time_scheme_state_t) :: scheme_state
      real(dp), allocatable :: x_before(:, :)
      real(dp) :: t
      integer(ip) :: step, k

      stat = FOLD_OK
      errmsg = ""
      if (scheme /= FOLD_EULER .and. scheme /= FOLD_AB2) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0)') "stokes_march: scheme must be 1 (Euler) or 2 (Adams-Bashforth 2), got ", scheme
         return
      end if
      if (.not. (dt > 0.0_dp) .or. nsteps < 0) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,es10.3,a,i0)') "stokes_march: need dt > 0 and nsteps >= 0, got dt ", dt, &
            ", nsteps ", nsteps
         return
      end if
      call scheme_state%init(scheme, 1_ip, parts%dim, parts%n)
      x_hist(:, :, 0) = parts%x
      p_hist(:, :, 0) = parts%p
      do step = 1, nsteps
         t = t0 + (step - 1)*dt
         call cell_set_time(cell, t)
         call stokes_rigid_velocities(ctx, cell, parts, recs(step), stat, errmsg)
         if (stat /= FOLD_OK) then
            write (errmsg, '(a,i0,a,a)') "stokes_march: step ", step, ": ", trim(errmsg)
            return
         end if
         call scheme_state%push_solve(parts%v, parts%omega, t)
         call scheme_state%step_velocity(t, parts%v, parts%omega)
         call rigid_update(parts, dt)
         ! wrapping applies the Lees-Edwards jump to the stored velocity too, so
         ! the AB2 combination at the next step stays in one frame
         x_before = parts%x
         do k = 1, parts%n
            call cell_wrap(cell, parts%x(:, k), parts%v(:, k))
         end do
         call scheme_state%carry_across_wrap(cell, x_before)
         x_hist(:, :, step) = parts%x
         p_hist(:, :, step) = parts%p
      end do
   end subroutine stokes_march

end module fold_stokes_step
