!> The penalty physics above the Stokes seam, shared by every backend: the checks and
!> the mean strain rate that begin a solve, the viscosity of a voxel partly covered by
!> the particles (chi -> eta mixing) and the verdict on a solve (tolerance reached, not
!> converged, or a NaN residual).
!>
!> Mixing rules (fold_stokes_solver FOLD_MIX_*), chi the covered fraction of a voxel
!> and kappa the viscosity contrast of the solid:
!>   arithmetic  eta = eta_f (1 + (kappa - 1) chi)            (Voigt bound)
!>   harmonic    1/eta = (1 - chi)/eta_f + chi/(kappa eta_f)   (Reuss bound, the default)
!>   geometric   eta = eta_f kappa^chi
!> (docs/physics.md). The exact-rigidity solver (fold_stokes_rigid) has no kappa; it
!> shares the verdict only.
module fold_penalty
   use, intrinsic :: ieee_arithmetic, only: ieee_is_nan
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NOT_CONVERGED, FOLD_NUMERICAL
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, FOLD_MIX_HARMONIC, FOLD_MIX_GEOMETRIC
   use fold_settings, only: FOLD_RIGIDITY_NAME, FOLD_RIGIDITY_USES_KAPPA
   implicit none
   private

   public :: solve_begin, penalty_viscosity, solve_verdict

contains

   !> Begin a solve of s (named who in messages): the lattice must be set and chi must
   !> cover this rank's slab (n(1), nl(2), nl(3)); then s%E = sym(G), without the z row
   !> and column in 2-D.
   subroutine solve_begin(s, lattice_set, chi, G, who, stat, errmsg)
      class(stokes_solver_t), intent(inout) :: s
      !> The solver's lattice has been set (set_lattice)
      logical, intent(in) :: lattice_set
      !> Solid volume fraction of each local voxel [-]
      real(dp), intent(in) :: chi(:, :, :)
      !> Mean velocity gradient [1/s]
      real(dp), intent(in) :: G(3, 3)
      character(len=*), intent(in) :: who
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_OK
      errmsg = ""
      if (.not. lattice_set) then
         stat = FOLD_INPUT_ERROR
         errmsg = who//": call set_lattice first"
         return
      end if
      if (any(shape(chi) /= [s%grid%n(1), s%grid%nl(2), s%grid%nl(3)])) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,a,3(1x,i0),a,3(1x,i0))') who, ": chi must have shape", s%grid%n(1), s%grid%nl(2:3), &
            ", got", shape(chi)
         return
      end if
      s%E = 0.5_dp*(G + transpose(G))
      if (s%dim == 2) then
         s%E(3, :) = 0.0_dp
         s%E(:, 3) = 0.0_dp
      end if
   end subroutine solve_begin

   !> Viscosity of every voxel of chi by the mixing rule of the settings [Pa s].
   subroutine penalty_viscosity(set, chi, eta)
      type(stokes_settings_t), intent(in) :: set
      !> Covered fraction of each voxel [-]
      real(dp), intent(in) :: chi(:, :, :)
      !> Viscosity, same shape as chi [Pa s]
      real(dp), intent(out) :: eta(:, :, :)
      select case (set%mixing)
      case (FOLD_MIX_HARMONIC)
         eta = set%eta_f/((1.0_dp - chi) + chi/set%kappa)
      case (FOLD_MIX_GEOMETRIC)
         eta = set%eta_f*set%kappa**chi
      case default
         eta = set%eta_f*(1.0_dp + (set%kappa - 1.0_dp)*chi)
      end select
   end subroutine penalty_viscosity

   !> The verdict on a solve that stopped after iterations steps at residual: stat and
   !> errmsg are left as they are when residual <= set%tol; otherwise FOLD_NUMERICAL (NaN)
   !> or FOLD_NOT_CONVERGED with a message naming the solver (who), its iteration
   !> (method, e.g. "CG"), the residual reached, the tolerance and the rigidity
   !> (kappa, or "rigidity exact" where the residual is the rigidity error).
   subroutine solve_verdict(set, who, method, iterations, residual, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      !> Name of the solve in the message
      character(len=*), intent(in) :: who, method
      integer(ip), intent(in) :: iterations
      !> Relative residual reached [-]
      real(dp), intent(in) :: residual
      integer, intent(inout) :: stat
      character(len=msg_len), intent(inout) :: errmsg
      if (residual <= set%tol) return
      if (ieee_is_nan(residual)) then
         stat = FOLD_NUMERICAL
         errmsg = who//": residual is NaN"
      else if (.not. FOLD_RIGIDITY_USES_KAPPA(set%rigidity)) then
         stat = FOLD_NOT_CONVERGED
         write (errmsg, '(a,a,i0,a,a,a,es10.3,a,es10.3,a)') who, ": not converged after ", iterations, " ", method, &
            " iterations: rigidity error ", residual, " > tol ", set%tol, " (rigidity "// &
            trim(FOLD_RIGIDITY_NAME(set%rigidity))//")"
      else
         stat = FOLD_NOT_CONVERGED
         write (errmsg, '(a,a,i0,a,a,a,es10.3,a,es10.3,a,es10.3,a)') who, ": not converged after ", iterations, " ", &
            method, " iterations: residual ", residual, " > tol ", set%tol, " (kappa ", set%kappa, ")"
      end if
   end subroutine solve_verdict

end module fold_penalty
