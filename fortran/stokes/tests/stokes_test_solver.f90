!> What the MPI tests in fortran/stokes/tests share: the start and end of a test
!> program over MPI_COMM_WORLD, and the solver of the FFT tests, made by the factory on
!> a sheared (Lees-Edwards) lattice, the program stopped when it cannot be made.
module stokes_test_solver
   use mpi_f08, only: MPI_COMM_WORLD, MPI_Abort, MPI_Init, MPI_Comm_rank, MPI_Finalize
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_grid, only: shear_lattice
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   use fold_stokes_factory, only: stokes_solver_create
   use fold_stokes_fft, only: stokes_fft_t
   use stokes_test_check, only: check, check_start, check_passed
   implicit none
   private

   public :: sheared_solver, mpi_test_start, mpi_test_end

contains

   !> Start a test program: MPI_Init, this process's rank in MPI_COMM_WORLD, no failure
   !> yet, failure lines named name and printed by rank 0.
   subroutine mpi_test_start(name, rank, failures)
      character(len=*), intent(in) :: name
      integer, intent(out) :: rank, failures
      call MPI_Init()
      call MPI_Comm_rank(MPI_COMM_WORLD, rank)
      failures = 0
      call check_start(name, rank == 0)
   end subroutine mpi_test_start

   !> End a test program: the verdict line, then MPI_Finalize, or MPI_Abort with
   !> exit code 1 when a check failed.
   subroutine mpi_test_end(failures)
      integer, intent(in) :: failures
      if (.not. check_passed(failures)) call MPI_Abort(MPI_COMM_WORLD, 1)
      call MPI_Finalize()
   end subroutine mpi_test_end

   !> A 3-D solver of the settings on n voxels with the lattice of lengths (1, 0.9, 1.1)
   !> and offset 0.3; an FFT solver must have the stencil form of its operator.
   subroutine sheared_solver(set, n, s, failures)
      type(stokes_settings_t), intent(in) :: set
      integer(ip), intent(in) :: n(3)
      class(stokes_solver_t), allocatable, intent(out) :: s
      integer, intent(inout) :: failures
      integer :: stat
      character(len=msg_len) :: msg
      call stokes_solver_create(set, 3, n, MPI_COMM_WORLD, s, stat, msg)
      call check(stat == FOLD_OK, "create: "//trim(msg), failures)
      if (stat /= FOLD_OK) call MPI_Abort(MPI_COMM_WORLD, 1)
      call s%set_lattice(shear_lattice([1.0_dp, 0.9_dp, 1.1_dp], 0.3_dp), stat, msg)
      call check(stat == FOLD_OK, "set_lattice: "//trim(msg), failures)
      select type (s)
      class is (stokes_fft_t)
         call check(s%stencil_ok, "the 3-D rotated-difference solver has the stencil form", failures)
      end select
   end subroutine sheared_solver

end module stokes_test_solver
