!> Exact Jeffery step for a constant velocity gradient: the rigid velocities that
!> carry every particle over one time step to Jeffery's exact solution.
!>
!> Jeffery's equation dp/dt = W.p + xi (D.p - (p.D.p) p) (Jeffery 1922, Proc. R. Soc.
!> A 102:161) is dp/dt = M.p - (p.M.p) p with M = W + xi D, whose solution for a
!> constant M is
!>     p(t + dt) = E.p / |E.p|,   E = exp(dt M)
!> (the orientation of a material line in the flow M; Bretherton 1962, J. Fluid Mech.
!> 14:284; Junk & Illner 2007, J. Math. Fluid Mech. 9:455). `fold_kinematics`
!> returns the instantaneous angular velocity and rotates with it frozen over the
!> step (Lie-Euler, first order in dt): a dilute run then drifts from the Jeffery
!> orbit by O(dt), enough to spoil a 1e-6 comparison with Folgar-Tucker at C_I = 0.
!> Here the angular velocity of the step is instead the constant rotation vector
!> that turns p into the exact p(t + dt): axis p x p', angle atan2(|p x p'|, p.p'),
!> omega = axis * angle / dt, so the exact rigid update (Rodrigues) of
!> `fold_kinematics::rigid_update` lands on Jeffery's solution to round-off. For
!> xi = 0 (spheres, and any body that only spins) the exact motion is the constant
!> spin omega = vorticity/2 of `jeffery_omega`, used as is. For xi /= 0 the axial
!> spin (omega_f . p) p is left out: it does not move an axisymmetric body or any
!> point of its axis, and a rotation vector with an axial part would not map p to p'.
!> Translation: v = u_mean(x) of `fold_cell` (exact over the step in simple shear,
!> where u_x depends on y only and y does not change).
!> E = exp(dt M) depends only on xi for the run's constant G and dt: it is computed
!> once per distinct xi (scaling and squaring of the Taylor series, Moler & Van Loan
!> 2003, SIAM Rev. 45:3, method 3), so the per-step cost is one matrix-vector product.
module fold_jeffery_step
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_cell, only: cell_t, cell_mean_velocity
   use fold_particles, only: particle_set_t
   use fold_kinematics, only: jeffery_omega
   ! expm3 lives in fold_matrix_exp (also used by fold_cell); re-exported here
   use fold_matrix_exp, only: expm3
   implicit none
   private

   !> Propagators exp(dt M(xi)) for the distinct shape factors of a particle set.
   type, public :: jeffery_stepper_t
      integer(ip) :: dim = 3
      !> Time step the propagators are for [s]
      real(dp) :: dt = 0.0_dp
      !> Velocity gradient G_ij [1/s]
      real(dp) :: G(3, 3) = 0.0_dp
      !> Distinct xi values
      real(dp), allocatable :: xi(:)
      !> exp(dt (W + xi D)) for each distinct xi, E(3, 3, nxi)
      real(dp), allocatable :: E(:, :, :)
      !> Index into xi/E of each particle
      integer(ip), allocatable :: which(:)
   end type jeffery_stepper_t

   public :: jeffery_stepper_init, jeffery_step_velocities, expm3

contains

   !> Precompute the propagators for the particles' shape factors.
   subroutine jeffery_stepper_init(st, parts, G, dt, stat, errmsg)
      type(jeffery_stepper_t), intent(out) :: st
      type(particle_set_t), intent(in) :: parts
      !> Constant velocity gradient G_ij = du_i/dx_j [1/s]
      real(dp), intent(in) :: G(3, 3)
      !> Time step (> 0) [s]
      real(dp), intent(in) :: dt
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp) :: Dm(3, 3), Wm(3, 3), uniq(parts%n)
      integer(ip) :: k, m, nu

      stat = FOLD_OK
      errmsg = ""
      if (.not. (dt > 0.0_dp)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,es10.3)') "jeffery_stepper_init: dt must be > 0, got ", dt
         return
      end if
      st%dim = parts%dim
      st%dt = dt
      st%G = G
      Dm = 0.5_dp*(G + transpose(G))
      Wm = 0.5_dp*(G - transpose(G))
      if (parts%dim == 2) then
         Dm(3, :) = 0.0_dp; Dm(:, 3) = 0.0_dp
         Wm(3, :) = 0.0_dp; Wm(:, 3) = 0.0_dp
      end if
      allocate (st%which(parts%n))
      nu = 0
      do k = 1, parts%n
         m = findloc(uniq(1:nu), parts%xi(k), dim=1)
         if (m == 0) then
            nu = nu + 1
            uniq(nu) = parts%xi(k)
            m = nu
         end if
         st%which(k) = m
      end do
      st%xi = uniq(1:nu)
      allocate (st%E(3, 3, nu))
      do m = 1, nu
         st%E(:, :, m) = expm3(dt*(Wm + st%xi(m)*Dm))
      end do
   end subroutine jeffery_stepper_init

   !> v and omega of particles first..last for the step from t to t + dt.
   subroutine jeffery_step_velocities(st, cell, parts, first, last)
      type(jeffery_stepper_t), intent(in) :: st
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      !> Range of particles to set (this MPI rank's block)
      integer(ip), intent(in) :: first, last
      real(dp) :: p(3), q(3), ax(3), sn, cs
      integer(ip) :: k, d

      d = parts%dim
      do k = first, last
         parts%v(:, k) = cell_mean_velocity(cell, parts%x(:, k))
         if (st%xi(st%which(k)) == 0.0_dp) then
            parts%omega(:, k) = jeffery_omega(d, st%G, parts%p(:, k), 0.0_dp)
            cycle
         end if
         p = 0.0_dp
         p(1:d) = parts%p(:, k)
         q = matmul(st%E(:, :, st%which(k)), p)
         q = q/norm2(q)
         ax = [p(2)*q(3) - p(3)*q(2), p(3)*q(1) - p(1)*q(3), p(1)*q(2) - p(2)*q(1)]
         cs = dot_product(p, q)
         parts%omega(:, k) = 0.0_dp
         if (d == 2) then
            parts%omega(3, k) = atan2(ax(3), cs)/st%dt
         else
            sn = norm2(ax)
            ! p' = p: no rotation; a NaN from an overflowing propagator must propagate
            if (.not. (sn == 0.0_dp)) parts%omega(:, k) = ax/sn*atan2(sn, cs)/st%dt
         end if
      end do
   end subroutine jeffery_step_velocities

end module fold_jeffery_step
