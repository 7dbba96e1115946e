! Thin f2py layer over the fictitious-domain Stokes solver (backend fft, serial FFTW
! transport). Each call makes the solver through fold_stokes_build::stokes_serial_create
! (the construction fold_run uses on one rank), solves and frees everything, so Python
! holds no native state; explicit-shape arguments let stokes.pyf hide the sizes.
module fold_stokes_bind_util
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t
   implicit none
   private
   public :: make_settings, velocity_out
contains
   !> u(:, :, :, c) <- component c of the solver's velocity at the voxel centres (after
   !> compute_velocity), without the padding of its rows [m/s].
   subroutine velocity_out(s, u)
      class(stokes_solver_t), intent(in) :: s
      real(dp), intent(inout) :: u(:, :, :, :)
      real(dp), pointer, contiguous :: f(:, :, :)
      integer(ip) :: c
      do c = 1, int(size(u, 4), ip)
         f => s%velocity_field(c)
         u(:, :, :, c) = f(1:size(u, 1), :, :)
      end do
   end subroutine velocity_out

   function make_settings(eta_f, kappa, tol, max_iter, derivative, mixing, subsamples, fibre_ends, warm_start, &
                          plan_effort, rigidity, fibre_radius_scale, fibre_shells) result(set)
      real(dp), intent(in) :: eta_f, kappa, tol, fibre_radius_scale
      !> fold_settings FOLD_SHELLS_* (default: overlap)
      integer(ip), intent(in), optional :: fibre_shells
      integer(ip), intent(in) :: max_iter, derivative, mixing, subsamples, fibre_ends, warm_start, plan_effort
      !> fold_settings FOLD_RIGIDITY_*
      integer(ip), intent(in) :: rigidity
      type(stokes_settings_t) :: set
      ! warm_start: 0 cold (zero guess), else the guess code (fold_stokes_fft FOLD_GUESS_*:
      ! 1 previous solution, 2 extrapolated from the last two)
      set = stokes_settings_t(eta_f=eta_f, kappa=kappa, tol=tol, max_iter=max_iter, derivative=derivative, &
                              mixing=mixing, subsamples=subsamples, fibre_ends=fibre_ends, &
                              warm_start=warm_start /= 0, guess=max(1_ip, min(int(warm_start, ip), 2_ip)), &
                              plan_effort=plan_effort, rigidity=rigidity, fibre_radius_scale=fibre_radius_scale)
      if (present(fibre_shells)) set%fibre_shells = fibre_shells
   end function make_settings
end module fold_stokes_bind_util

subroutine fold_stokes_solve_chi(dim, n1, n2, n3, lattice, g, chi, eta_f, kappa, tol, max_iter, derivative, mixing, &
                                 plan_effort, rigidity_code, u, stress, eta_eff, eta_diss, iterations, residual, history, &
                                 stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_NOT_CONVERGED
   use fold_stokes_solver, only: stokes_solver_t
   use fold_stokes_build, only: stokes_serial_create
   use fold_stress, only: bulk_stress_t, bulk_stress
   use fold_stokes_bind_util, only: make_settings, velocity_out
   implicit none
   integer(ip), intent(in) :: dim, n1, n2, n3, max_iter, derivative, mixing, plan_effort, rigidity_code
   real(dp), intent(in) :: lattice(3, 3), g(3, 3), chi(n1, n2, n3), eta_f, kappa, tol
   real(dp), intent(out) :: u(n1, n2, n3, dim), stress(3, 3), eta_eff, eta_diss, residual, history(max_iter + 1)
   integer(ip), intent(out) :: iterations
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   class(stokes_solver_t), allocatable :: s
   type(bulk_stress_t) :: b
   integer :: solve_stat
   character(len=msg_len) :: solve_msg

   u = 0.0_dp
   stress = 0.0_dp
   eta_eff = 0.0_dp
   eta_diss = 0.0_dp
   residual = 0.0_dp
   history = 0.0_dp
   iterations = 0
   ! chi is given: the voxelisation settings (subsamples, ends, radius scale) are unused
   call stokes_serial_create(make_settings(eta_f, kappa, tol, max_iter, derivative, mixing, 1_ip, 0_ip, 0_ip, &
                                           plan_effort, rigidity_code, 1.0_dp), dim, [n1, n2, n3], s, stat, errmsg)
   if (stat /= FOLD_OK) return
   call s%set_lattice(lattice, stat, errmsg)
   if (stat /= FOLD_OK) return
   call s%solve(chi, g, solve_stat, solve_msg)
   iterations = s%iterations
   residual = s%residual
   history(1:iterations + 1) = s%history(0:iterations)
   if (solve_stat == FOLD_OK .or. solve_stat == FOLD_NOT_CONVERGED) then
      call s%compute_velocity()
      call velocity_out(s, u)
      call bulk_stress(s, chi, b, stat, errmsg)
      stress = b%sigma
      eta_eff = b%eta_eff
      eta_diss = b%eta_dissipation
   end if
   stat = solve_stat
   errmsg = solve_msg
   call s%destroy()
end subroutine fold_stokes_solve_chi

subroutine fold_stokes_solve_particles(dim, n1, n2, n3, np, lengths, shear_offset, g, shape, radius, length, xi, x, p, &
                                       eta_f, kappa, tol, max_iter, derivative, mixing, subsamples, fibre_ends, &
                                       fibre_radius_scale, fibre_shells, shell_gap, plan_effort, rigidity_code, chi, u, v, omega, &
                                       rigidity, stress, sigma_p, scalars, &
                                       iterations, history, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_NOT_CONVERGED
   use fold_cell, only: cell_t, cell_init
   use fold_particles, only: particle_set_t, particles_init
   use fold_stokes_step
   use fold_stokes_bind_util, only: make_settings, velocity_out
   implicit none
   integer(ip), intent(in) :: dim, n1, n2, n3, np, max_iter, derivative, mixing, subsamples, fibre_ends, plan_effort, rigidity_code
   integer(ip), intent(in) :: shape(np)
   real(dp), intent(in) :: lengths(3), shear_offset, g(3, 3), radius(np), length(np), xi(np), x(dim, np), p(dim, np)
   !> radius of the voxelised fibres over their geometric radius (fold_voxelise)
   real(dp), intent(in) :: eta_f, kappa, tol, fibre_radius_scale
   !> the added shells of near fibres (FOLD_SHELLS_*) and, kept apart, their gap [m]
   integer(ip), intent(in) :: fibre_shells
   real(dp), intent(in) :: shell_gap
   real(dp), intent(out) :: chi(n1, n2, n3), u(n1, n2, n3, dim), v(dim, np), omega(3, np), rigidity(np)
   !> scalars: residual, eta_eff, eta_dissipation, solid_strain, solid_fraction
   real(dp), intent(out) :: stress(3, 3), sigma_p(3, 3), scalars(5), history(max_iter + 1)
   integer(ip), intent(out) :: iterations
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(stokes_context_t) :: ctx
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   type(stokes_record_t) :: rec

   chi = 0.0_dp
   u = 0.0_dp
   v = 0.0_dp
   omega = 0.0_dp
   rigidity = 0.0_dp
   stress = 0.0_dp
   sigma_p = 0.0_dp
   scalars = 0.0_dp
   history = 0.0_dp
   iterations = 0
   call cell_init(cell, dim, lengths, .false., g, stat, errmsg)
   if (stat /= FOLD_OK) return
   cell%shear_offset = shear_offset
   call particles_init(parts, dim, np, stat, errmsg, x=x, p=p, shape=shape, radius=radius, length=length, xi=xi)
   if (stat /= FOLD_OK) return
   call stokes_context_init(ctx, make_settings(eta_f, kappa, tol, max_iter, derivative, mixing, subsamples, &
                                               fibre_ends, 0_ip, plan_effort, rigidity_code, fibre_radius_scale, &
                                               fibre_shells), &
                            dim, [n1, n2, n3], &
                            stat, errmsg)
   if (stat /= FOLD_OK) return
   call stokes_context_lubrication(ctx, .false., shell_gap)
   call stokes_rigid_velocities(ctx, cell, parts, rec, stat, errmsg)
   iterations = ctx%solver%iterations
   history(1:iterations + 1) = ctx%solver%history(0:iterations)
   if (stat == FOLD_OK .or. stat == FOLD_NOT_CONVERGED) then
      chi = ctx%vox%chi
      call velocity_out(ctx%solver, u)
      v = parts%v
      omega = parts%omega
      rigidity = ctx%rigidity
      stress = rec%bulk%sigma
      sigma_p = rec%bulk%sigma_particles
      scalars = [rec%residual, rec%bulk%eta_eff, rec%bulk%eta_dissipation, rec%bulk%solid_strain, &
                 rec%bulk%solid_fraction]
   end if
   call stokes_context_destroy(ctx)
end subroutine fold_stokes_solve_particles

subroutine fold_stokes_march(dim, n1, n2, n3, np, nsteps, lengths, g, t0, dt, scheme, shape, radius, length, xi, &
                             x0, p0, eta_f, kappa, tol, max_iter, derivative, mixing, subsamples, fibre_ends, &
                             fibre_radius_scale, warm_start, plan_effort, rigidity_code, x_hist, p_hist, records, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK
   use fold_cell, only: cell_t, cell_init
   use fold_particles, only: particle_set_t, particles_init
   use fold_stokes_step
   use fold_stokes_bind_util, only: make_settings
   implicit none
   integer(ip), intent(in) :: dim, n1, n2, n3, np, nsteps, scheme, max_iter, derivative, mixing, subsamples
   integer(ip), intent(in) :: fibre_ends, warm_start, plan_effort, rigidity_code, shape(np)
   real(dp), intent(in) :: lengths(3), g(3, 3), t0, dt, radius(np), length(np), xi(np), x0(dim, np), p0(dim, np)
   !> radius of the voxelised fibres over their geometric radius (fold_voxelise)
   real(dp), intent(in) :: eta_f, kappa, tol, fibre_radius_scale
   real(dp), intent(out) :: x_hist(dim, np, nsteps + 1), p_hist(dim, np, nsteps + 1)
   !> records(:, step): iterations, residual, rigidity_max, eta_eff, solid_strain, solid_fraction,
   !> residual of the initial guess
   real(dp), intent(out) :: records(7, nsteps)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   type(stokes_context_t) :: ctx
   type(cell_t) :: cell
   type(particle_set_t) :: parts
   type(stokes_record_t), allocatable :: recs(:)
   integer :: k

   x_hist = 0.0_dp
   p_hist = 0.0_dp
   records = 0.0_dp
   call cell_init(cell, dim, lengths, .false., g, stat, errmsg)
   if (stat /= FOLD_OK) return
   call particles_init(parts, dim, np, stat, errmsg, x=x0, p=p0, shape=shape, radius=radius, length=length, xi=xi)
   if (stat /= FOLD_OK) return
   call stokes_context_init(ctx, make_settings(eta_f, kappa, tol, max_iter, derivative, mixing, subsamples, &
                                               fibre_ends, warm_start, plan_effort, rigidity_code, &
                                               fibre_radius_scale), dim, &
                            [n1, n2, n3], stat, errmsg)
   if (stat /= FOLD_OK) return
   allocate (recs(max(nsteps, 1)))
   call stokes_march(ctx, cell, parts, t0, dt, nsteps, scheme, x_hist, p_hist, recs, stat, errmsg)
   do k = 1, nsteps
      records(:, k) = [real(recs(k)%iterations, dp), recs(k)%residual, recs(k)%rigidity_max, recs(k)%bulk%eta_eff, &
                       recs(k)%bulk%solid_strain, recs(k)%bulk%solid_fraction, recs(k)%residual0]
   end do
   call stokes_context_destroy(ctx)
end subroutine fold_stokes_march

!> The largest viscosity contrast the solver carries on nvox voxels at tolerance tol with
!> transforms of precision fft_precision (0 double, 1 single), the largest tolerance that
!> carries kappa, and the operator's relative round-off eps_op there (fold_stokes_trust,
!> the one place they are computed).
subroutine fold_stokes_kappa_max(nvox, tol, kappa, fft_precision, kmax, tmax, eps_op)
   use fold_kinds, only: dp, ip, i8
   use fold_stokes_trust, only: kappa_max, tolerance_max, operator_roundoff
   implicit none
   integer(i8), intent(in) :: nvox
   real(dp), intent(in) :: tol, kappa
   integer(ip), intent(in) :: fft_precision
   real(dp), intent(out) :: kmax, tmax, eps_op
   kmax = kappa_max(nvox, tol, fft_precision)
   tmax = tolerance_max(nvox, kappa, fft_precision)
   eps_op = operator_roundoff(nvox, fft_precision)
end subroutine fold_stokes_kappa_max

!> fold_run's run-time check of a solve's effective viscosity (fold_stokes_trust).
subroutine fold_stokes_stress_check(eta_eff, eta_f, nvox, kappa, tol, stat, errmsg)
   use fold_kinds, only: dp, i8, msg_len
   use fold_stokes_trust, only: stokes_stress_check
   implicit none
   real(dp), intent(in) :: eta_eff, eta_f, kappa, tol
   integer(i8), intent(in) :: nvox
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   call stokes_stress_check(eta_eff, eta_f, nvox, kappa, tol, stat, errmsg)
end subroutine fold_stokes_stress_check
