!> Time schemes of the loops that march particles with velocities computed from the
!> flow (fold_stokes_step::stokes_march and the run driver, fold_driver).
!>
!> The rigid velocities of a Stokes solve are combined in time by explicit Euler
!> (v_n) or Adams-Bashforth 2 (3/2 v_n - 1/2 v_(n-1); the first step, without a
!> history, is Euler); positions and orientations are then moved exactly
!> (fold_kinematics::rigid_update). The codes are those of /setup/resolved/time_scheme
!> and of pyfold/native/stokes.py SCHEMES.
module fold_time_scheme
   use fold_kinds, only: dp, ip
   implicit none
   private

   !> Time-stepping schemes
   integer(ip), parameter, public :: FOLD_EULER = 1, FOLD_AB2 = 2

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

end module fold_time_scheme
