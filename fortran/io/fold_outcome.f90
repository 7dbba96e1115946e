!> A run's outcome as structured root attributes of the run file, beside the
!> human-readable `status`:
!>   outcome           the enumeration name below (OUTCOME_NAMES)
!>   outcome_step      the step the run ended at: nsteps when completed, the failing
!>                     step otherwise (the state in the file is that of `steps_done`)
!>   outcome_time      the time of that step [s]
!>   outcome_cause     the cause of a failure ("" when completed or running)
!>   outcome_residual  relative residual of the last Stokes solve (NaN without a solver)
!> The codes 1..5 are those of fold_status (the status a failing step returned).
!> pyfold/outcome.py reads them (OUTCOMES there lists the same names in the same order).
module fold_outcome
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use fold_kinds, only: dp, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_NUMERICAL
   use fold_h5, only: hid_t, h5_attr_string, h5_attr_int, h5_attr_real
   implicit none
   private

   !> Outcome codes
   integer, parameter, public :: OUTCOME_COMPLETED = 0, OUTCOME_INPUT_ERROR = 1, OUTCOME_NOT_CONVERGED = 2, &
                                 OUTCOME_IO_ERROR = 3, OUTCOME_CONTACT_CAP = 4, OUTCOME_BLOW_UP = 5, &
                                 OUTCOME_UNTRUSTED_STRESS = 6, OUTCOME_INTERRUPTED = 7, OUTCOME_RUNNING = 8
   !> Their names, as written in the attribute `outcome`
   character(len=*), parameter, public :: OUTCOME_NAMES(0:8) = [character(len=16) :: &
      "completed", "input_error", "not_converged", "io_error", "contact_cap", "blow_up", &
      "untrusted_stress", "interrupted", "running"]

   !> How a run ended (or that it is running).
   type, public :: outcome_t
      integer :: code = OUTCOME_RUNNING
      !> Step and time [s] the run ended at
      integer(i8) :: step = 0
      real(dp) :: time = 0.0_dp
      !> Cause of a failure
      character(len=msg_len) :: cause = ""
      !> Relative residual of the last Stokes solve [-] (NaN: none)
      real(dp) :: residual = 0.0_dp
   end type outcome_t

   public :: outcome_of_status, outcome_in_progress, outcome_write

contains

   !> The outcome code of a failing step's status (FOLD_INPUT_ERROR .. FOLD_NUMERICAL).
   pure integer function outcome_of_status(stat) result(code)
      integer, intent(in) :: stat
      if (stat >= FOLD_OK .and. stat <= FOLD_NUMERICAL) then
         code = stat
      else
         code = OUTCOME_INPUT_ERROR
      end if
   end function outcome_of_status

   !> The outcome of a run that has not ended.
   function outcome_in_progress() result(o)
      type(outcome_t) :: o
      o%code = OUTCOME_RUNNING
      o%residual = ieee_value(1.0_dp, ieee_quiet_nan)
   end function outcome_in_progress

   !> Write the outcome attributes on `loc` (the run file's root).
   subroutine outcome_write(loc, o, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      type(outcome_t), intent(in) :: o
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_attr_string(loc, "outcome", trim(OUTCOME_NAMES(o%code)), stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_int(loc, "outcome_step", o%step, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_real(loc, "outcome_time", o%time, stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_string(loc, "outcome_cause", trim(o%cause), stat, errmsg); if (stat /= FOLD_OK) return
      call h5_attr_real(loc, "outcome_residual", o%residual, stat, errmsg)
   end subroutine outcome_write

end module fold_outcome
