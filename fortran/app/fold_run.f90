!> fold_run RUNFILE [--resume] -- the pyfold direct simulation (MPI executable).
!>
!> Reads /setup/resolved and /initial of RUNFILE, appends the results to it (see
!> fold_output) and exits with
!>   0  success,
!>   1  numerical blow-up, unresolvable overlap or I/O failure during the run (the
!>      file keeps the last good state; its `status` attribute gives step, time, cause),
!>   2  bad command line or run file (the message names the dataset and the allowed range).
!> Rank 0 prints `PROGRESS <step> <nsteps> <t>` lines (at most ~100) on stdout; other
!> messages start with `fold_run:`. This is the only program unit that stops the program.
program fold_run
   use, intrinsic :: iso_fortran_env, only: output_unit, error_unit
   use, intrinsic :: iso_c_binding, only: c_int, c_intptr_t
   use mpi_f08
   use fold_status, only: FOLD_OK
   use fold_version, only: fold_version_string, fold_git_revision
   use fold_driver, only: run_outcome_t, run_driver
   use fold_h5, only: h5_wedged
   implicit none

   interface
      !> sighandler_t signal(int signum, sighandler_t handler), handlers passed as integers
      integer(c_intptr_t) function c_signal(signum, handler) bind(C, name="signal")
         import :: c_int, c_intptr_t
         integer(c_int), value :: signum
         integer(c_intptr_t), value :: handler
      end function c_signal
      !> void _exit(int status): ends the process without exit handlers
      subroutine c_exit(status) bind(C, name="_exit")
         import :: c_int
         integer(c_int), value :: status
      end subroutine c_exit
   end interface
   !> SIGXFSZ (Linux) and SIG_IGN
   integer(c_int), parameter :: SIGXFSZ = 25_c_int
   integer(c_intptr_t), parameter :: SIG_IGN = 1_c_intptr_t

   type(run_outcome_t) :: outcome
   character(len=4096) :: arg, path
   logical :: resume
   integer :: rank, nargs, k, code

   ! A file-size limit (ulimit -f) makes a write fail with EFBIG instead of killing
   ! the process with SIGXFSZ (the Fortran runtime's handler would print a backtrace):
   ! the run then stops like on a full disk, with exit 1 and the file's last good state.
   if (c_signal(SIGXFSZ, SIG_IGN) == -1_c_intptr_t) continue
   call MPI_Init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   path = ""
   resume = .false.
   nargs = command_argument_count()
   do k = 1, nargs
      call get_command_argument(k, arg)
      select case (trim(arg))
      case ("--resume")
         resume = .true.
      case ("--version")
         if (rank == 0) write (output_unit, '(a)') "fold_run "//fold_version_string//" ("//fold_git_revision//")"
         call MPI_Finalize()
         stop 0, quiet=.true.
      case default
         if (arg(1:1) == "-" .or. len_trim(path) > 0) then
            call usage("unexpected argument '"//trim(arg)//"'")
         end if
         path = arg
      end select
   end do
   if (len_trim(path) == 0) call usage("missing RUNFILE")

   call run_driver(trim(path), resume, outcome)
   code = 0
   if (outcome%stat /= FOLD_OK) then
      if (outcome%bad_input) then
         code = 2
         if (rank == 0) write (error_unit, '(a)') "fold_run: bad run file "//trim(path)//": "//trim(outcome%errmsg)
      else
         code = 1
         if (rank == 0) write (error_unit, '(a)') "fold_run: "//trim(outcome%errmsg)
      end if
   else if (rank == 0) then
      write (output_unit, '(a,i0,a,es23.16)') "fold_run: done, ", outcome%steps_done, " steps, t = ", outcome%time
   end if
   flush (output_unit)
   flush (error_unit)
   if (h5_wedged()) then
      ! A file HDF5 could not close: terminating the library (MPI_Finalize runs its
      ! exit hook) would crash on it (HDF5 < 1.14.1). Leave without exit handlers.
      write (error_unit, '(a)') "fold_run: the run file could not be closed; ending without MPI_Finalize"
      flush (error_unit)
      call c_exit(int(max(code, 1), c_int))
   end if
   call MPI_Finalize()
   if (code /= 0) stop code, quiet=.true.

contains

   subroutine usage(why)
      character(len=*), intent(in) :: why
      if (rank == 0) write (error_unit, '(a)') "fold_run: "//why//"; usage: fold_run RUNFILE [--resume]"
      call MPI_Finalize()
      stop 2, quiet=.true.
   end subroutine usage

end program fold_run
