!> The serial construction of the Stokes solvers, shared by every caller: the Python
!> extensions (fortran/bind/stokes_bind.f90 through fold_stokes_step::stokes_context_init),
!> the tests and the factory of the executables (fold_stokes_factory), which adds the
!> MPI-only paths (FFTW-MPI slabs, hypre) on top. No MPI here, so the extensions link it.
!>
!> The settings are checked once per construction, by the entry that a caller uses
!> (stokes_serial_create here, stokes_solver_create in the factory);
!> stokes_transport_solver assumes checked settings.
module fold_stokes_build
   use fold_kinds, only: ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_fft_transport, only: fft_transport_t
   use fold_fft_serial, only: fft_serial_t, fft_serial_create
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, stokes_settings_check, FOLD_RIGIDITY_EXACT, &
                                 stokes_backend_t, stokes_backend, stokes_backend_name
   use fold_stokes_fft, only: stokes_fft_new
   use fold_stokes_rigid, only: stokes_rigid_new
   implicit none
   private

   public :: stokes_serial_create, stokes_transport_solver

contains

   !> A solver of backend set%backend on a dim-dimensional grid of n(1:dim) voxels in
   !> this process (serial FFTW transport). On failure solver is not allocated and
   !> errmsg names the setting.
   subroutine stokes_serial_create(set, dim, n, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      !> Spatial dimension (2 or 3) and voxel counts (n(3) = 1 in 2-D)
      integer(ip), intent(in) :: dim, n(3)
      class(stokes_solver_t), allocatable, intent(out) :: solver
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      class(fft_transport_t), allocatable :: fft
      type(fft_serial_t), allocatable :: serial
      type(stokes_backend_t) :: b

      call stokes_settings_check(set, stat, errmsg)
      if (stat /= FOLD_OK) return
      b = stokes_backend(set%backend)
      if (.not. (b%serial .and. b%fft_transport)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "stokes settings: backend "//stokes_backend_name(set%backend)// &
                  " needs MPI (fold_run); only backend fft runs in one process"
         return
      end if
      allocate (serial)
      call fft_serial_create(serial, dim, n, set%plan_effort, stat, errmsg)
      if (stat == FOLD_OK) call move_alloc(serial, fft)
      call stokes_transport_solver(set, fft, solver, stat, errmsg)
   end subroutine stokes_serial_create

   !> The solver built on an FFT transport made by the caller (serial or FFTW-MPI), of
   !> the rigidity the settings ask for: exact (fold_stokes_rigid) or the penalty
   !> (fold_stokes_fft). Settings already checked. On failure solver is not allocated.
   subroutine stokes_transport_solver(set, fft, solver, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      !> Transport; moved into the solver (deallocated on return)
      class(fft_transport_t), allocatable, intent(inout) :: fft
      class(stokes_solver_t), allocatable, intent(out) :: solver
      !> On entry, the status and message of the transport's creation: a failure is
      !> reported as the grid's; on return, the construction's
      integer, intent(inout) :: stat
      character(len=msg_len), intent(inout) :: errmsg
      if (stat /= FOLD_OK) then
         errmsg = "grid: "//trim(errmsg)
         return
      end if
      if (set%rigidity == FOLD_RIGIDITY_EXACT) then
         call stokes_rigid_new(fft, set, solver, stat, errmsg)
      else
         call stokes_fft_new(fft, set, solver, stat, errmsg)
      end if
   end subroutine stokes_transport_solver

end module fold_stokes_build
