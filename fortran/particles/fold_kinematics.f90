!> Jeffery kinematics of a particle set and the exact rigid update.
!>
!> Dilute (no hydrodynamic interaction) rigid velocities in the imposed flow:
!>     V = u_mean(x) = G.(x - c)              (frame rule of fold_cell)
!>     dp/dt = W.p + xi (D.p - (p.D.p) p)      (Jeffery 1922, Proc. R. Soc. A 102:161)
!> with D = (G + G^T)/2, W = (G - G^T)/2 and xi = (be^2 - 1)/(be^2 + 1) (set by Python).
!> The angular velocity returned is the rigid rotation that produces this dp/dt:
!>     omega = p x dp/dt + (omega_f . p) p,  omega_f = vorticity/2 (the axial spin),
!> so a sphere (xi = 0) spins at half the vorticity, gamma_dot/2 in shear. In 2-D the
!> scalar rate omega(3) = p x dp/dt.
!>
!> rigid_update moves x by v dt and turns p by the EXACT rotation of angle |omega| dt
!> about omega (Rodrigues' formula; an angle increment in 2-D). It never renormalises
!> p: |p| = 1 and the fibre length (distance of the end points x +/- L/2 p) are kept to
!> round-off by construction, which the tests measure. Time integration with
!> velocities frozen over the step (Lie-Euler on the rotation group) is first order.
module fold_kinematics
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_cell, only: cell_t, cell_mean_velocity
   use fold_particles, only: particle_set_t
   implicit none
   private

   public :: jeffery_velocities, jeffery_omega, rigid_update, rotate_axis, cross

contains

   !> Angular velocity (3 components; 2-D: only the third is meaningful) of a particle
   !> with unit axis p and shape factor xi in the gradient G (dim x dim part used).
   pure function jeffery_omega(dim, G, p, xi) result(omega)
      integer(ip), intent(in) :: dim
      !> Velocity gradient G_ij = du_i/dx_j [1/s]
      real(dp), intent(in) :: G(3, 3)
      !> Unit axis (dim) [-]
      real(dp), intent(in) :: p(:)
      !> Jeffery shape factor [-]
      real(dp), intent(in) :: xi
      real(dp) :: omega(3)
      real(dp) :: Dm(3, 3), Wm(3, 3), p3(3), pdot(3), wf(3)

      Dm = 0.5_dp*(G + transpose(G))
      Wm = 0.5_dp*(G - transpose(G))
      p3 = 0.0_dp
      p3(1:dim) = p(1:dim)
      if (dim == 2) then
         Dm(3, :) = 0.0_dp; Dm(:, 3) = 0.0_dp
         Wm(3, :) = 0.0_dp; Wm(:, 3) = 0.0_dp
      end if
      pdot = matmul(Wm, p3) + xi*(matmul(Dm, p3) - dot_product(p3, matmul(Dm, p3))*p3)
      omega = cross(p3, pdot)
      if (dim == 3) then
         ! vorticity/2 as a vector: W.a = wf x a  with wf = (W32, W13, W21)
         wf = [Wm(3, 2), Wm(1, 3), Wm(2, 1)]
         omega = omega + dot_product(wf, p3)*p3
      end if
   end function jeffery_omega

   !> Set v and omega of every particle to its dilute Jeffery values.
   subroutine jeffery_velocities(cell, parts, stat, errmsg)
      type(cell_t), intent(in) :: cell
      type(particle_set_t), intent(inout) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: k

      stat = FOLD_OK
      errmsg = ""
      if (cell%dim /= parts%dim) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a,i0)') "jeffery_velocities: cell dim ", cell%dim, " /= particle dim ", parts%dim
         return
      end if
      do k = 1, parts%n
         parts%v(:, k) = cell_mean_velocity(cell, parts%x(:, k))
         parts%omega(:, k) = jeffery_omega(parts%dim, cell%G, parts%p(:, k), parts%xi(k))
      end do
   end subroutine jeffery_velocities

   !> p turned by the rotation vector phi = omega dt (exact; Rodrigues in 3-D).
   pure function rotate_axis(dim, p, omega, dt) result(q)
      integer(ip), intent(in) :: dim
      real(dp), intent(in) :: p(:)
      real(dp), intent(in) :: omega(3)
      real(dp), intent(in) :: dt
      real(dp) :: q(dim)
      real(dp) :: ang, c, s, k(3), p3(3), q3(3)

      if (dim == 2) then
         ang = omega(3)*dt
         c = cos(ang)
         s = sin(ang)
         q = [c*p(1) - s*p(2), s*p(1) + c*p(2)]
      else
         ang = norm2(omega)*dt
         if (ang == 0.0_dp) then
            q = p(1:3)
            return
         end if
         k = omega/norm2(omega)
         p3 = p(1:3)
         c = cos(ang)
         s = sin(ang)
         ! Rodrigues: q = p cos + (k x p) sin + k (k.p)(1 - cos)
         q3 = p3*c + cross(k, p3)*s + k*dot_product(k, p3)*(1.0_dp - c)
         q = q3
      end if
   end function rotate_axis

   !> x += v dt; p turned exactly by omega dt. Positions are NOT wrapped here (the
   !> driver calls cell_wrap, which also applies the Lees-Edwards velocity jump).
   pure subroutine rigid_update(parts, dt)
      type(particle_set_t), intent(inout) :: parts
      !> Time step [s]
      real(dp), intent(in) :: dt
      integer(ip) :: k
      do k = 1, parts%n
         parts%x(:, k) = parts%x(:, k) + parts%v(:, k)*dt
         parts%p(:, k) = rotate_axis(parts%dim, parts%p(:, k), parts%omega(:, k), dt)
      end do
   end subroutine rigid_update

   !> a x b (3-D vectors).
   pure function cross(a, b) result(c)
      real(dp), intent(in) :: a(3), b(3)
      real(dp) :: c(3)
      c = [a(2)*b(3) - a(3)*b(2), a(3)*b(1) - a(1)*b(3), a(1)*b(2) - a(2)*b(1)]
   end function cross

end module fold_kinematics
