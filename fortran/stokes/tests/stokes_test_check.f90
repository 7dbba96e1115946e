!> What the native tests of fortran/stokes/tests share: check counts a failed condition
!> and prints it (on the printing rank, with the program's name set by check_start),
!> and ball_chi gives the characteristic function of a ball on a rank's slab.
module stokes_test_check
   use fold_kinds, only: dp, ip
   implicit none
   private

   !> Name of the program, start of every failure line, and whether this process prints
   character(len=64) :: program_name = "", prefix = "FAILED: "
   logical :: prints = .true.

   public :: check, check_start, check_passed, ball_chi

contains

   !> Name the program in failure lines; only the process with loud = .true. prints.
   subroutine check_start(name, loud)
      character(len=*), intent(in) :: name
      logical, intent(in) :: loud
      program_name = name
      prefix = name//": FAILED: "
      prints = loud
   end subroutine check_start

   !> The verdict line of the program ("<name>: ok" or the number of failed checks);
   !> true when every check passed.
   logical function check_passed(failures) result(passed)
      integer, intent(in) :: failures
      passed = failures == 0
      if (.not. prints) return
      if (passed) then
         print '(a)', trim(program_name)//": ok"
      else
         print '(a,a,i0,a)', trim(program_name), ": ", failures, " check(s) failed"
      end if
   end function check_passed

   !> Count a failed check (ok false) and print what failed.
   subroutine check(ok, what, failures)
      logical, intent(in) :: ok
      character(len=*), intent(in) :: what
      integer, intent(inout) :: failures
      if (.not. ok) then
         failures = failures + 1
         if (prints) print '(a,a)', trim(prefix)//" ", trim(what)
      end if
   end subroutine check

   !> Covered fraction of a ball of radius 0.3 cell lengths centred at centre (in cell
   !> units) on the voxels (n(1), nl2, nl3) of a slab along z from plane off3, with a
   !> one-voxel partial-volume ramp [-].
   function ball_chi(n, nl2, nl3, off3, centre) result(chi)
      integer(ip), intent(in) :: n(3), nl2, nl3, off3
      real(dp), intent(in) :: centre
      real(dp) :: chi(n(1), nl2, nl3)
      real(dp) :: nv
      integer :: i, j, k
      do k = 1, nl3
         do j = 1, nl2
            do i = 1, n(1)
               nv = sqrt(sum(((real([i - 1, j - 1, k - 1 + off3], dp) + 0.5_dp)/real(n, dp) - centre)**2))
               chi(i, j, k) = min(1.0_dp, max(0.0_dp, (0.3_dp - nv)*real(n(1), dp) + 0.5_dp))
            end do
         end do
      end do
   end function ball_chi

end module stokes_test_check
