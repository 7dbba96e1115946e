!> Rigid motion of each particle from the computed flow (chi-weighted least squares).
!>
!> Over the voxels of particle k (centres at r = x_voxel - x_k, unwrapped) minimise sum w |u - V - omega x r|^2 with
!> u = u_mean(x_k) + G r + u~ (frame rule of fold_cell). The normal equations
!>   [ W0 I    -[m]x ] [V    ]   [ sum w u     ]
!>   [ [m]x     I_r  ] [omega] = [ sum w r x u ],
!> W0 = sum w, m = sum w r, I_r = sum w (|r|^2 I - r r^T), are the rigid-body
!> "mass matrix" of the chi distribution (a fit over all cells is more robust than
!> moving two end points, docs/physics.md#rigid-motion-fit-and-update). In 2-D the
!> unknowns are (Vx, Vy, w_z).
!> Moments are summed over the local slab and then over ranks, so every rank
!> gets the same (V, omega). The rigidity residual of particle k is
!>   sqrt(sum w |u - V - omega x r|^2 / W0) / (|E| l_k),
!> |E| = sqrt(2 E:E) (= gamma_dot in shear), l_k = max(L/2, R): the non-rigid
!> part of the velocity relative to the imposed velocity differences across the
!> particle; it falls like 1/kappa (penalty error,
!> docs/physics.md#penalty-too-soft-for-long-fibres).
module fold_rigid_fit
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_stokes_solver, only: stokes_solver_t, field_ref_t
   use fold_voxelise, only: voxel_set_t
   use fold_particles, only: particle_set_t
   use fold_kinematics, only: cross
   use fold_cell, only: cell_t, cell_mean_velocity
   implicit none
   private

   public :: rigid_fit

contains

   !> Fit (V, omega) of every particle: writes parts%v, parts%omega and resid.
   subroutine rigid_fit(solver, cell, vox, parts, resid, stat, errmsg)
      !> Solver after a solve and compute_velocity: u~ and the viscosity at the voxel
      !> centres, eta_f and kappa of its settings, the sums over ranks
      class(stokes_solver_t), intent(in) :: solver
      !> Cell: mean flow u_mean = G.(x - c)
      type(cell_t), intent(in) :: cell
      !> Voxel lists of the particles (local slab)
      type(voxel_set_t), intent(in) :: vox
      type(particle_set_t), intent(inout) :: parts
      !> Rigidity residual of each particle [-]
      real(dp), intent(out) :: resid(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      type(field_ref_t) :: vel(3), eta
      real(dp) :: eta_f, kappa
      integer(ip), parameter :: nm3 = 16, nm2 = 7
      integer(ip) :: dim, k, nm, c, info
      integer(i8) :: e
      real(dp), allocatable :: mom(:, :), dev(:)
      real(dp) :: G(3, 3), Ed(3, 3), r(3), u(3), w, mat(6, 6), rhs(6), sol(6), gnorm, ell, ur(3), om(3)

      stat = FOLD_OK
      errmsg = ""
      dim = parts%dim
      if (vox%n /= parts%n .or. size(resid) < parts%n .or. solver%dim /= dim) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a,i0)') "rigid_fit: voxel lists for ", vox%n, " particles, set has ", parts%n
         return
      end if
      do c = 1, dim
         vel(c)%r => solver%velocity_field(c)
      end do
      eta%r => solver%viscosity_field()
      eta_f = solver%set%eta_f
      kappa = solver%set%kappa
      G = cell%G
      if (dim == 2) then
         G(3, :) = 0.0_dp
         G(:, 3) = 0.0_dp
      end if
      nm = merge(nm3, nm2, dim == 3)
      allocate (mom(nm, parts%n), dev(parts%n))
      mom = 0.0_dp
      do k = 1, parts%n
         do e = vox%ptr(k), vox%ptr(k + 1) - 1
            w = vox%frac(e)*penalty_weight(e)
            r = vox%rel(:, e)
            u = matmul(G, r)
            do c = 1, dim
               u(c) = u(c) + vel(c)%r(vox%ijk(1, e), vox%ijk(2, e), vox%ijk(3, e))
            end do
            if (dim == 3) then
               mom(1, k) = mom(1, k) + w
               mom(2:4, k) = mom(2:4, k) + w*r
               mom(5:7, k) = mom(5:7, k) + w*r**2
               mom(8, k) = mom(8, k) + w*r(1)*r(2)
               mom(9, k) = mom(9, k) + w*r(1)*r(3)
               mom(10, k) = mom(10, k) + w*r(2)*r(3)
               mom(11:13, k) = mom(11:13, k) + w*u
               mom(14:16, k) = mom(14:16, k) + w*cross(r, u)
            else
               mom(1, k) = mom(1, k) + w
               mom(2:3, k) = mom(2:3, k) + w*r(1:2)
               mom(4, k) = mom(4, k) + w*(r(1)**2 + r(2)**2)
               mom(5:6, k) = mom(5:6, k) + w*u(1:2)
               mom(7, k) = mom(7, k) + w*(r(1)*u(2) - r(2)*u(1))
            end if
         end do
      end do
      ! sum the whole moment table over ranks in one reduction
      call sum_table(solver, mom)

      do k = 1, parts%n
         if (.not. (mom(1, k) > 0.0_dp)) then
            stat = FOLD_INPUT_ERROR
            write (errmsg, '(a,i0,a)') "rigid_fit: particle ", k, " covers no voxel (smaller than the grid can see)"
            return
         end if
         mat = 0.0_dp
         if (dim == 3) then
            mat(1, 1) = mom(1, k); mat(2, 2) = mom(1, k); mat(3, 3) = mom(1, k)
            ! -[m]x in the upper right, [m]x in the lower left
            mat(1:3, 4:6) = -crossmat(mom(2:4, k))
            mat(4:6, 1:3) = crossmat(mom(2:4, k))
            mat(4, 4) = mom(6, k) + mom(7, k); mat(5, 5) = mom(5, k) + mom(7, k); mat(6, 6) = mom(5, k) + mom(6, k)
            mat(4, 5) = -mom(8, k); mat(5, 4) = -mom(8, k)
            mat(4, 6) = -mom(9, k); mat(6, 4) = -mom(9, k)
            mat(5, 6) = -mom(10, k); mat(6, 5) = -mom(10, k)
            rhs = mom(11:16, k)
            call solve_small(6, mat, rhs, sol, info)
         else
            mat(1, 1) = mom(1, k); mat(2, 2) = mom(1, k)
            mat(1, 3) = -mom(3, k); mat(3, 1) = -mom(3, k)
            mat(2, 3) = mom(2, k); mat(3, 2) = mom(2, k)
            mat(3, 3) = mom(4, k)
            rhs(1:3) = mom(5:7, k)
            call solve_small(3, mat(1:3, 1:3), rhs(1:3), sol(1:3), info)
         end if
         if (info /= 0) then
            stat = FOLD_NUMERICAL
            write (errmsg, '(a,i0,a)') "rigid_fit: singular rigid-motion fit for particle ", k, &
               " (too few voxels: refine the grid)"
            return
         end if
         if (dim == 3) then
            parts%v(:, k) = cell_mean_velocity(cell, parts%x(:, k)) + sol(1:3)
            parts%omega(:, k) = sol(4:6)
         else
            parts%v(:, k) = cell_mean_velocity(cell, parts%x(:, k)) + sol(1:2)
            parts%omega(:, k) = [0.0_dp, 0.0_dp, sol(3)]
         end if
      end do

      ! second pass: non-rigid part of the velocity
      dev = 0.0_dp
      do k = 1, parts%n
         ur = 0.0_dp
         ur(1:dim) = parts%v(:, k) - cell_mean_velocity(cell, parts%x(:, k))
         om = parts%omega(:, k)
         do e = vox%ptr(k), vox%ptr(k + 1) - 1
            r = vox%rel(:, e)
            u = matmul(G, r)
            do c = 1, dim
               u(c) = u(c) + vel(c)%r(vox%ijk(1, e), vox%ijk(2, e), vox%ijk(3, e))
            end do
            u = u - ur - cross(om, r)
            dev(k) = dev(k) + vox%frac(e)*penalty_weight(e)*sum(u(1:dim)**2)
         end do
      end do
      call solver%sum_all(dev)
      Ed = 0.5_dp*(G + transpose(G))
      gnorm = sqrt(2.0_dp*sum(Ed**2))
      if (.not. (gnorm > 0.0_dp)) gnorm = sqrt(sum(G**2))
      if (.not. (gnorm > 0.0_dp)) gnorm = 1.0_dp
      do k = 1, parts%n
         ell = max(0.5_dp*parts%length(k), parts%radius(k))
         resid(k) = sqrt(dev(k)/mom(1, k))/(gnorm*ell)
      end do
   contains

      !> (eta - eta_f) / ((kappa - 1) eta_f chi) at the voxel of entry e (1 without contrast).
      !> Under exact rigidity 1: the fit weights every voxel by the particle's coverage. (The
      !> penalised weights vanish like 1/kappa on the partly covered voxels, which would
      !> leave a thin particle without a fully covered voxel unmeasured in the limit.)
      real(dp) function penalty_weight(e)
         integer(i8), intent(in) :: e
         real(dp) :: chi
         chi = vox%chi(vox%ijk(1, e), vox%ijk(2, e), vox%ijk(3, e))
         if (solver%exact_rigidity) then
            penalty_weight = 1.0_dp
         else if (kappa > 1.0_dp .and. chi > 0.0_dp) then
            penalty_weight = (eta%r(vox%ijk(1, e), vox%ijk(2, e), vox%ijk(3, e)) - eta_f)/((kappa - 1.0_dp)*eta_f*chi)
         else
            penalty_weight = 1.0_dp
         end if
      end function penalty_weight

   end subroutine rigid_fit

   subroutine sum_table(solver, t)
      class(stokes_solver_t), intent(in) :: solver
      real(dp), intent(inout), target, contiguous :: t(:, :)
      real(dp), pointer :: flat(:)
      if (size(t) == 0) return
      flat(1:size(t)) => t
      call solver%sum_all(flat)
   end subroutine sum_table

   !> [a]x: the matrix with [a]x b = a x b.
   pure function crossmat(a) result(m)
      real(dp), intent(in) :: a(3)
      real(dp) :: m(3, 3)
      m = reshape([0.0_dp, a(3), -a(2), -a(3), 0.0_dp, a(1), a(2), -a(1), 0.0_dp], [3, 3])
   end function crossmat

   !> Gaussian elimination with partial pivoting for an n x n system (n <= 6).
   pure subroutine solve_small(n, a_in, b_in, x, info)
      integer, intent(in) :: n
      real(dp), intent(in) :: a_in(n, n), b_in(n)
      real(dp), intent(out) :: x(n)
      integer, intent(out) :: info
      real(dp) :: a(n, n), b(n), f, scale, row(n), t
      integer :: i, j, piv
      a = a_in
      b = b_in
      info = 0
      scale = maxval(abs(a))
      if (.not. (scale > 0.0_dp)) then
         info = 1
         x = 0.0_dp
         return
      end if
      do i = 1, n
         piv = i - 1 + maxloc(abs(a(i:n, i)), 1)
         if (abs(a(piv, i)) <= 1.0e-13_dp*scale) then
            info = 1
            x = 0.0_dp
            return
         end if
         if (piv /= i) then
            row = a(i, :); a(i, :) = a(piv, :); a(piv, :) = row
            t = b(i); b(i) = b(piv); b(piv) = t
         end if
         do j = i + 1, n
            f = a(j, i)/a(i, i)
            a(j, i:n) = a(j, i:n) - f*a(i, i:n)
            b(j) = b(j) - f*b(i)
         end do
      end do
      do i = n, 1, -1
         x(i) = (b(i) - sum(a(i, i + 1:n)*x(i + 1:n)))/a(i, i)
      end do
   end subroutine solve_small

end module fold_rigid_fit
