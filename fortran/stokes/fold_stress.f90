!> Bulk (volume-averaged) stress of the suspension and its effective viscosity.
!>
!> Polarisation average (Batchelor 1970, J. Fluid Mech. 41:545;
!> docs/physics.md#bulk-stress-and-effective-viscosity):
!>   Sigma = -<p> I + 2 eta_f E + (1/V) int 2 (eta - eta_f) eps(u) dV,
!> with eps(u) = E + eps(u~) and <eps(u~)> = 0 on the periodic cell. The mean
!> pressure of an incompressible periodic flow is arbitrary: we report the
!> deviatoric part (<p> = 0), Sigma' = <2 eta eps(u)>. Effective viscosity
!>   eta_eff = Sigma' : E / (2 E : E)    (= Sigma_xy / gamma_dot in simple shear),
!> and, independently, from the dissipation <2 eta eps:eps> / (2 E:E); Hill's
!> lemma makes the two equal for an exactly balanced field, so their difference
!> measures the solver error. All sums are over voxel centres (volume weight dv).
!> Under exact rigidity (fold_stokes_rigid) eta = eta_f everywhere and the particles'
!> contribution is the polarisation's mean stress <tau> and dissipation <tau : eps>; the
!> solid strain ratio is then taken over the rigid voxels (chi >= FOLD_RIGID_COVERAGE).
module fold_stress
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_grid, only: grid_total
   use fold_stokes_solver, only: stokes_solver_t, field_ref_t, FOLD_RIGID_COVERAGE
   implicit none
   private

   !> Bulk stress and viscosities of one solve.
   type, public :: bulk_stress_t
      !> Deviatoric bulk stress Sigma' = <2 eta eps(u)> (3 x 3; 2-D in the upper 2 x 2) [Pa]
      real(dp) :: sigma(3, 3) = 0.0_dp
      !> Particle (polarisation) contribution <2 (eta - eta_f) eps(u)> [Pa]
      real(dp) :: sigma_particles(3, 3) = 0.0_dp
      !> Effective viscosity Sigma':E/(2 E:E) [Pa s]
      real(dp) :: eta_eff = 0.0_dp
      !> Effective viscosity from the dissipation <2 eta eps:eps>/(2 E:E) [Pa s]
      real(dp) :: eta_dissipation = 0.0_dp
      !> Solid strain ratio sqrt(<s eps:eps>/<s>) / sqrt(E:E), s = (eta - eta_f)/((kappa-1) eta_f)
      !> the relative penalty (= chi for arithmetic mixing): rigidity error in strain form [-]
      real(dp) :: solid_strain = 0.0_dp
      !> Mean of chi: discrete solid volume fraction [-]
      real(dp) :: solid_fraction = 0.0_dp
   end type bulk_stress_t

   public :: bulk_stress

contains

   !> Bulk stress of the last solve of s (computes the strain of u~: nc FFTs).
   subroutine bulk_stress(s, chi, out, stat, errmsg)
      class(stokes_solver_t), intent(inout) :: s
      !> Characteristic function on the local slab (nx, n2l, n3l) [-]
      real(dp), intent(in) :: chi(:, :, :)
      type(bulk_stress_t), intent(out) :: out
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: c, a, b, nx, i, j, k
      type(field_ref_t) :: work(6), eta
      real(dp) :: red(2*6 + 4), ee, eps(6), mult(6), et, diss, solid, chisum, ntot, ef, pen

      stat = FOLD_OK
      errmsg = ""
      nx = s%grid%n(1)
      if (any(shape(chi) /= [nx, s%grid%nl(2), s%grid%nl(3)])) then
         stat = FOLD_INPUT_ERROR
         errmsg = "bulk_stress: chi does not match the solver grid"
         return
      end if
      call s%compute_strain()
      do c = 1, s%nc
         work(c)%r => s%strain_field(c)
      end do
      eta%r => s%viscosity_field()
      ef = s%set%eta_f
      mult = 0.0_dp
      do c = 1, s%nc
         mult(c) = merge(1.0_dp, 2.0_dp, s%ci(c) == s%cj(c))
      end do
      red = 0.0_dp
      do k = 1, s%grid%nl(3)
         do j = 1, s%grid%nl(2)
            do i = 1, nx
               et = eta%r(i, j, k)
               do c = 1, s%nc
                  eps(c) = s%E(s%ci(c), s%cj(c)) + work(c)%r(i, j, k)
               end do
               diss = sum(mult(1:s%nc)*eps(1:s%nc)**2)
               red(1:s%nc) = red(1:s%nc) + 2.0_dp*et*eps(1:s%nc)
               red(7:6 + s%nc) = red(7:6 + s%nc) + 2.0_dp*(et - ef)*eps(1:s%nc)
               red(13) = red(13) + 2.0_dp*et*diss
               pen = 0.0_dp
               if (s%exact_rigidity) then
                  ! the solid voxels, where the strain left is the rigidity error
                  if (chi(i, j, k) >= FOLD_RIGID_COVERAGE) pen = 1.0_dp
               else if (s%set%kappa > 1.0_dp) then
                  pen = (et - ef)/((s%set%kappa - 1.0_dp)*ef)
               end if
               red(14) = red(14) + pen*diss
               red(15) = red(15) + chi(i, j, k)
               red(16) = red(16) + pen
            end do
         end do
      end do
      call s%sum_all(red)
      ntot = real(grid_total(s%grid), dp)
      red = red/ntot
      do c = 1, s%nc
         a = s%ci(c)
         b = s%cj(c)
         out%sigma(a, b) = red(c)
         out%sigma(b, a) = red(c)
         out%sigma_particles(a, b) = red(6 + c)
         out%sigma_particles(b, a) = red(6 + c)
      end do
      if (s%exact_rigidity) then
         ! the particles' stress and dissipation are the polarisation's (eta = eta_f everywhere)
         out%sigma = out%sigma + s%multiplier_stress
         out%sigma_particles = s%multiplier_stress
         red(13) = red(13) + s%multiplier_dissipation
      end if
      ee = sum(s%E**2)
      if (ee > 0.0_dp) then
         out%eta_eff = sum(out%sigma*s%E)/(2.0_dp*ee)
         out%eta_dissipation = red(13)/(2.0_dp*ee)
      end if
      chisum = red(15)
      out%solid_fraction = chisum
      solid = 0.0_dp
      if (red(16) > 0.0_dp .and. ee > 0.0_dp) solid = sqrt(red(14)/red(16)/ee)
      out%solid_strain = solid
   end subroutine bulk_stress

end module fold_stress
