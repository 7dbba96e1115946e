!> When the penalised Stokes solve can be trusted: the allowed range of the viscosity
!> contrast kappa at a grid, tolerance and transform precision, and the run-time check
!> of the bulk stress (docs/physics.md#how-large-a-penalty-the-solver-can-carry).
!>
!> Allowed range. Let u~ be the exact disturbance flow, u~_k the CG iterate it stops at,
!> r = b - A u~_k its residual (A, b, M of fortran/stokes/fold_stokes_fft.f90, M the
!> Green-operator preconditioner eta0 |k|^2 P), phi the solid fraction and
!> Delta = (eta_eff - eta_f)/eta_f the particles' share of the effective viscosity.
!>  1. Error of eta_eff: eta_eff is linear in u~, and A is symmetric, so
!>        eta_eff(u~_k) - eta_eff(u~) = -<u~, r> / (2 V E:E),
!>     and |<u~, r>| <= |u~|_M |r|_M^-1 (Cauchy-Schwarz in the M inner product).
!>  2. |u~|_M^2 = eta0 int |grad u~|^2 = 2 eta0 int eps(u~):eps(u~) = 2 eta0 V E:E Delta
!>     (divergence-free periodic u~; the last equality is the dissipation identity of
!>     rigid particles, where eps(u~) = -E inside).
!>  3. b = -P B^H tau, tau = 2 (eta - eta_f) E, |tau| <= 2 (kappa - 1) eta_f |E| chi, and
!>     |P(tau k)|^2 <= |tau|^2 |k|^2 / 2 for a traceless symmetric tau, so
!>     |b|_M^-1^2 <= |tau|^2 / (2 eta0) <= 2 (kappa - 1)^2 eta_f^2 phi V E:E / eta0.
!>  4. CG stops at |r|_M^-1 <= tol |b|_M^-1 on its recursive residual; the true one is
!>     farther by the round-off of the operator, eps_op = (2 log2 N + 4) u for N voxels
!>     and the unit round-off u of the transforms (2^-53 double, 2^-24 single; the
!>     derivation of fold_stokes_fft's header). eta0 cancels between 2 and 3:
!>        |delta eta_eff| <= (kappa - 1) (tol + eps_op) eta_f sqrt(phi Delta).
!>  5. The stress of a solid voxel is 2 kappa eta_f (E + eps(u~)), a cancellation:
!>     eps(u~) carries the round-off eps_d of the double-precision transforms that give
!>     the strain (always double: fold_stokes_fft), so the sum adds at most
!>     kappa eps_d eta_f phi.
!> Relative to the contribution eta_f Delta, with Delta >= phi (the solid alone gives
!> int eps(u~):eps(u~) >= phi V E:E), the error is at most
!>        delta = (kappa - 1) (tol + eps_op) + kappa eps_d.
!> kappa is allowed while delta <= 1: the computed eta_eff then stays >= eta_f, as the
!> exact one does (minimum dissipation: every viscosity >= eta_f), i.e. the sign of the
!> particles' contribution is guaranteed. That is
!>        kappa <= kappa_max = (1 + tol + eps_op) / (tol + eps_op + eps_d),
!> at most FOLD_KAPPA_MAX. The penalty error falls like 1/kappa while
!> the solver's grows like kappa tol, so beyond kappa_max a larger kappa buys a larger
!> error. The bound is the FFT solver's; the hypre backend takes the same rule.
!>
!> Run-time check. Whatever the settings, the exact eta_eff of particles at least as
!> viscous as the fluid is >= eta_f; a computed value below eta_f (less the round-off of
!> its N-term sums, N u_double) cannot be a result and ends the run.
module fold_stokes_trust
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_stokes_solver, only: stokes_settings_t, FOLD_KAPPA_MAX, FOLD_FFT_DOUBLE, FOLD_FFT_SINGLE
   use fold_stokes_fft, only: FOLD_SINGLE_ROUNDOFF
   implicit none
   private

   !> Unit round-off of double precision, 2^-53 [-]
   real(dp), parameter, public :: FOLD_DOUBLE_ROUNDOFF = 0.5_dp*epsilon(1.0_dp)

   public :: operator_roundoff, kappa_max, tolerance_max, stokes_kappa_check, stokes_stress_check

contains

   !> Relative round-off of the CG operator on nvox voxels with transforms of the given
   !> precision (FOLD_FFT_*): (2 log2 nvox + 4) u (fold_stokes_fft's header).
   pure function operator_roundoff(nvox, fft_precision) result(e)
      integer(i8), intent(in) :: nvox
      integer(ip), intent(in) :: fft_precision
      real(dp) :: e
      real(dp) :: u
      u = merge(FOLD_SINGLE_ROUNDOFF, FOLD_DOUBLE_ROUNDOFF, fft_precision == FOLD_FFT_SINGLE)
      e = u*(2.0_dp*log(real(max(nvox, 2_i8), dp))/log(2.0_dp) + 4.0_dp)
   end function operator_roundoff

   !> Largest kappa whose bound on the stress error stays within the particles'
   !> contribution: (1 + tol + eps_op)/(tol + eps_op + eps_d), at most FOLD_KAPPA_MAX
   !> (header; eps_d: the double-precision round-off).
   pure function kappa_max(nvox, tol, fft_precision) result(k)
      integer(i8), intent(in) :: nvox
      real(dp), intent(in) :: tol
      integer(ip), intent(in) :: fft_precision
      real(dp) :: k
      real(dp) :: e
      e = operator_roundoff(nvox, fft_precision)
      k = min(FOLD_KAPPA_MAX, (1.0_dp + tol + e)/(tol + e + operator_roundoff(nvox, FOLD_FFT_DOUBLE)))
   end function kappa_max

   !> Largest tolerance at which kappa (> 1) is allowed: (1 - (kappa - 1) eps_op - kappa eps_d)
   !> / (kappa - 1), 0 when no tolerance is small enough; huge for kappa <= 1.
   pure function tolerance_max(nvox, kappa, fft_precision) result(t)
      integer(i8), intent(in) :: nvox
      real(dp), intent(in) :: kappa
      integer(ip), intent(in) :: fft_precision
      real(dp) :: t
      if (kappa <= 1.0_dp) then
         t = huge(1.0_dp)
         return
      end if
      t = max(0.0_dp, (1.0_dp - (kappa - 1.0_dp)*operator_roundoff(nvox, fft_precision) - &
                       kappa*operator_roundoff(nvox, FOLD_FFT_DOUBLE))/(kappa - 1.0_dp))
   end function tolerance_max

   !> Refuse a kappa above kappa_max on a grid of nvox voxels (FOLD_INPUT_ERROR, the
   !> message naming kappa, its allowed range and the largest tolerance for this kappa).
   subroutine stokes_kappa_check(set, nvox, stat, errmsg)
      type(stokes_settings_t), intent(in) :: set
      integer(i8), intent(in) :: nvox
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp) :: kmax, e
      stat = FOLD_OK
      errmsg = ""
      kmax = kappa_max(nvox, set%tol, set%fft_precision)
      if (set%kappa <= kmax) return
      stat = FOLD_INPUT_ERROR
      e = operator_roundoff(nvox, set%fft_precision)
      write (errmsg, '(a,es10.3,a,i0,a,es9.2,a,a,a,es9.2,a,es10.3,a,es9.2,a)') &
         "stokes settings: kappa ", set%kappa, " is beyond what the solver resolves on ", nvox, &
         " voxels at tol ", set%tol, " with ", trim(merge("single", "double", set%fft_precision == FOLD_FFT_SINGLE)), &
         " transforms (stress error bound (kappa-1) (tol + eps_op) + kappa eps_d > 1 of the particles' share, "// &
         "eps_op = ", e, "); allowed: kappa in [1, ", kmax, "] or, for this kappa, tol <= ", &
         tolerance_max(nvox, set%kappa, set%fft_precision), &
         " (docs/physics.md#how-large-a-penalty-the-solver-can-carry)"
   end subroutine stokes_kappa_check

   !> Stop a run whose effective viscosity is below the fluid's (FOLD_NUMERICAL): the
   !> exact one is >= eta_f for every kappa >= 1, so the stress is not a result.
   !> eta_eff and eta_f [Pa s]; nvox voxels summed; kappa and tol for the message.
   subroutine stokes_stress_check(eta_eff, eta_f, nvox, kappa, tol, stat, errmsg)
      real(dp), intent(in) :: eta_eff, eta_f, kappa, tol
      integer(i8), intent(in) :: nvox
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_OK
      errmsg = ""
      if (eta_eff >= eta_f*(1.0_dp - real(nvox, dp)*FOLD_DOUBLE_ROUNDOFF)) return
      stat = FOLD_NUMERICAL
      write (errmsg, '(a,es11.4,a,es11.4,a,es10.3,a,es9.2,a)') "untrustworthy stress: effective viscosity ", eta_eff, &
         " Pa s below the fluid's ", eta_f, " Pa s, impossible for particles at least as viscous as the fluid "// &
         "(minimum dissipation); the solver's error exceeds the particles' contribution (kappa ", kappa, ", tol ", &
         tol, "; docs/physics.md#how-large-a-penalty-the-solver-can-carry)"
   end subroutine stokes_stress_check

end module fold_stokes_trust
