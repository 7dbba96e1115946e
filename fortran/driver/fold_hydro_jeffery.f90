!> Jeffery hydrodynamics (/setup/resolved/hydrodynamics = 0): v = u_mean(x) and the
!> exact Jeffery rotation of a step for constant G (fold_jeffery_step), computed for
!> this rank's block of particles and gathered on every rank. No flow is solved: the
!> time scheme's history stays empty and the records have no Stokes series.
module fold_hydro_jeffery
   use, intrinsic :: iso_fortran_env, only: output_unit
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK
   use fold_particles, only: particle_set_t
   use fold_cell, only: cell_t
   use fold_run_file, only: run_setup_t
   use fold_time_scheme, only: FOLD_EULER
   use fold_jeffery_step, only: jeffery_stepper_t, jeffery_stepper_init, jeffery_step_velocities
   use fold_hydro, only: hydro_model_t
   implicit none
   private

   public :: jeffery_init

   !> Exact Jeffery kinematics of the imposed flow.
   type, extends(hydro_model_t), public :: hydro_jeffery_t
      type(jeffery_stepper_t) :: stepper
      integer :: nranks = 1
      !> Counts and displacements of each rank's block in v (dim per particle) and omega (3)
      integer, allocatable :: count_v(:), offset_v(:), count_omega(:), offset_omega(:)
   contains
      procedure :: velocities => jeffery_velocities
   end type hydro_jeffery_t

contains

   !> Make the component for a run: the Jeffery stepper of the cell's velocity gradient
   !> and each rank's block of particles.
   subroutine jeffery_init(self, setup, cell, parts, rank, nranks, stat, errmsg)
      type(hydro_jeffery_t), intent(inout) :: self
      type(run_setup_t), intent(in) :: setup
      !> The run's cell (its velocity gradient)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(in) :: parts
      integer, intent(in) :: rank, nranks
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: r

      self%solves_flow = .false.
      self%residual = ieee_value(1.0_dp, ieee_quiet_nan)
      call self%scheme%init(FOLD_EULER, 1_ip, parts%dim, parts%n)
      call jeffery_stepper_init(self%stepper, parts, cell%G, setup%dt, stat, errmsg)
      if (stat /= FOLD_OK) return
      self%nranks = nranks
      allocate (self%count_v(nranks), self%offset_v(nranks))
      do r = 0, nranks - 1
         self%offset_v(r + 1) = int(int(r, i8)*parts%n/nranks)
         self%count_v(r + 1) = int(int(r + 1, i8)*parts%n/nranks) - self%offset_v(r + 1)
      end do
      self%offset_omega = 3*self%offset_v
      self%count_omega = 3*self%count_v
      self%offset_v = parts%dim*self%offset_v
      self%count_v = parts%dim*self%count_v
      if (setup%lubrication .and. rank == 0) write (output_unit, '(a)') &
         "fold_run: note: lubrication = 1 acts with the Stokes solver only (docs/physics.md#lubrication-between-spheres)"
   end subroutine jeffery_init

   subroutine jeffery_velocities(self, cell, parts, t, first, last)
      class(hydro_jeffery_t), intent(inout) :: self
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      real(dp), intent(in) :: t
      integer(ip), intent(in) :: first, last
      call jeffery_step_velocities(self%stepper, cell, parts, first, last)
      if (self%nranks > 1) then
         call MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, parts%v, self%count_v, self%offset_v, &
                             MPI_DOUBLE_PRECISION, MPI_COMM_WORLD)
         call MPI_Allgatherv(MPI_IN_PLACE, 0, MPI_DATATYPE_NULL, parts%omega, self%count_omega, self%offset_omega, &
                             MPI_DOUBLE_PRECISION, MPI_COMM_WORLD)
      end if
   end subroutine jeffery_velocities

end module fold_hydro_jeffery
