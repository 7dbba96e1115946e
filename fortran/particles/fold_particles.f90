!> The particle population of a direct simulation: fibres, spheres and spheroids.
!>
!> State lives in one derived type passed as an argument (no module state), so a
!> caller (run driver, Python binding, test) can hold several sets at once.
!> Geometry convention shared by placement and contacts: every particle is
!> handled, for overlap and contact purposes, as a *capsule* = the set of points
!> within `radius` of an axis segment of half-length `particle_half_segment`:
!>   * fibre    : cylinder radius R, length L; capsule over the full axis (L/2),
!>                which contains the cylinder (conservative at the flat ends);
!>   * sphere   : segment of zero length, the capsule *is* the sphere (length = 2R);
!>   * spheroid : prolate, semi-axes a = L/2, b = R; bounding capsule of half-length
!>                a - b, radius b, which contains the spheroid and touches it at the
!>                tips and at the equator (a bounding capsule, not the exact shape).
module fold_particles
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_check, only: check_dim
   implicit none
   private

   !> Shape code of a rigid cylindrical fibre (radius R, length L)
   integer(ip), parameter, public :: FOLD_FIBRE = 1
   !> Shape code of a sphere (2-D: a disk) of radius R
   integer(ip), parameter, public :: FOLD_SPHERE = 2
   !> Shape code of a prolate spheroid (2-D: an ellipse), major axis L, minor radius R
   integer(ip), parameter, public :: FOLD_SPHEROID = 3

   !> A population of rigid particles in a cell of dimension 2 or 3.
   type, public :: particle_set_t
      !> Spatial dimension (2 or 3)
      integer(ip) :: dim = 3
      !> Number of particles
      integer(ip) :: n = 0
      !> Shape code: FOLD_FIBRE, FOLD_SPHERE or FOLD_SPHEROID
      integer(ip), allocatable :: shape(:)
      !> Family index (0-based, as in the run file)
      integer(ip), allocatable :: family(:)
      !> Radius: fibre cross-section radius, sphere radius, spheroid minor semi-axis [m]
      real(dp), allocatable :: radius(:)
      !> Fibre cylinder length, spheroid major axis (2a), 2R for spheres [m]
      real(dp), allocatable :: length(:)
      !> Jeffery shape factor xi = (be^2-1)/(be^2+1) from the equivalent aspect ratio [-]
      real(dp), allocatable :: xi(:)
      !> Centres x(dim, n), kept in the primary cell [m]
      real(dp), allocatable :: x(:, :)
      !> Unit axes p(dim, n) [-]
      real(dp), allocatable :: p(:, :)
      !> Rigid translational velocities v(dim, n) [m/s]
      real(dp), allocatable :: v(:, :)
      !> Angular velocities omega(3, n); in 2-D only omega(3, :) is used [1/s]
      real(dp), allocatable :: omega(:, :)
   end type particle_set_t

   public :: particles_init, particles_check, particle_half_segment, particle_volume

contains

   !> Allocate a set of n particles in dimension dim; fields are zeroed, shapes set
   !> to fibres, axes to e_x, except the fields given (x, p, shape, radius, length,
   !> xi); the caller fills the others it needs.
   subroutine particles_init(parts, dim, n, stat, errmsg, x, p, shape, radius, length, xi)
      type(particle_set_t), intent(out) :: parts
      !> Spatial dimension (2 or 3)
      integer(ip), intent(in) :: dim
      !> Number of particles (>= 0)
      integer(ip), intent(in) :: n
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      !> Centres (dim, n) [m] and unit axes (dim, n) of the set, when given
      real(dp), intent(in), optional :: x(dim, n), p(dim, n)
      !> Shape codes, radii [m], lengths [m] and shape factors (n), when given
      integer(ip), intent(in), optional :: shape(n)
      real(dp), intent(in), optional :: radius(n), length(n), xi(n)

      call check_dim(dim, "particles_init", stat, errmsg)
      if (stat /= FOLD_OK) return
      if (n < 0) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0)') "particles_init: n must be >= 0, got ", n
         return
      end if
      parts%dim = dim
      parts%n = n
      allocate (parts%shape(n), parts%family(n), parts%radius(n), parts%length(n), parts%xi(n))
      allocate (parts%x(dim, n), parts%p(dim, n), parts%v(dim, n), parts%omega(3, n))
      parts%shape = FOLD_FIBRE
      parts%family = 0
      parts%radius = 0.0_dp
      parts%length = 0.0_dp
      parts%xi = 0.0_dp
      parts%x = 0.0_dp
      parts%p = 0.0_dp
      if (n > 0) parts%p(1, :) = 1.0_dp
      parts%v = 0.0_dp
      parts%omega = 0.0_dp
      if (present(x)) parts%x = x
      if (present(p)) parts%p = p
      if (present(shape)) parts%shape = shape
      if (present(radius)) parts%radius = radius
      if (present(length)) parts%length = length
      if (present(xi)) parts%xi = xi
   end subroutine particles_init

   !> Check that a filled set is physically meaningful: known shapes, R > 0,
   !> L >= 2R for spheroids, L = 2R for spheres (tolerance tol_rel), L > 0 for fibres,
   !> |xi| <= 1, |p| = 1 within tol_unit, all finite.
   subroutine particles_check(parts, stat, errmsg)
      type(particle_set_t), intent(in) :: parts
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      real(dp), parameter :: tol_unit = 1.0e-8_dp, tol_rel = 1.0e-10_dp
      integer(ip) :: k
      real(dp) :: pn

      call check_dim(parts%dim, "particles", stat, errmsg)
      if (stat /= FOLD_OK) return
      stat = FOLD_INPUT_ERROR
      if (.not. allocated(parts%x)) then
         errmsg = "particles: set not initialised (call particles_init)"
         return
      end if
      do k = 1, parts%n
         select case (parts%shape(k))
         case (FOLD_FIBRE)
            if (.not. (parts%length(k) > 0.0_dp)) then
               write (errmsg, '(a,i0,a,es10.3)') "particles: fibre ", k, " needs length > 0, got ", parts%length(k)
               return
            end if
         case (FOLD_SPHERE)
            if (abs(parts%length(k) - 2.0_dp*parts%radius(k)) > tol_rel*parts%radius(k)) then
               write (errmsg, '(a,i0,a,es10.3,a,es10.3)') "particles: sphere ", k, " needs length = 2*radius = ", &
                  2.0_dp*parts%radius(k), ", got ", parts%length(k)
               return
            end if
         case (FOLD_SPHEROID)
            if (parts%length(k) < 2.0_dp*parts%radius(k)*(1.0_dp - tol_rel)) then
               write (errmsg, '(a,i0,a,es10.3)') "particles: spheroid ", k, &
                  " must be prolate: length >= 2*radius, got length ", parts%length(k)
               return
            end if
         case default
            write (errmsg, '(a,i0,a,i0,a)') "particles: particle ", k, " has shape code ", parts%shape(k), &
               " (allowed 1 fibre, 2 sphere, 3 spheroid)"
            return
         end select
         if (.not. (parts%radius(k) > 0.0_dp)) then
            write (errmsg, '(a,i0,a,es10.3)') "particles: particle ", k, " needs radius > 0, got ", parts%radius(k)
            return
         end if
         if (.not. (abs(parts%xi(k)) <= 1.0_dp)) then
            write (errmsg, '(a,i0,a,es10.3)') "particles: particle ", k, " needs xi in [-1, 1], got ", parts%xi(k)
            return
         end if
         pn = norm2(parts%p(:, k))
         if (.not. (abs(pn - 1.0_dp) <= tol_unit)) then
            write (errmsg, '(a,i0,a,es12.5)') "particles: particle ", k, " needs a unit axis p, |p| = ", pn
            return
         end if
         if (.not. all(abs(parts%x(:, k)) <= huge(1.0_dp))) then
            write (errmsg, '(a,i0,a)') "particles: particle ", k, " has a non-finite centre"
            return
         end if
      end do
      stat = FOLD_OK
   end subroutine particles_check

   !> Half-length of the axis segment of the particle's (bounding) capsule [m]:
   !> L/2 for a fibre, 0 for a sphere, a - b = L/2 - R for a prolate spheroid.
   elemental function particle_half_segment(shape, radius, length) result(h)
      integer(ip), intent(in) :: shape
      real(dp), intent(in) :: radius, length
      real(dp) :: h
      select case (shape)
      case (FOLD_FIBRE)
         h = 0.5_dp*length
      case (FOLD_SPHEROID)
         h = max(0.0_dp, 0.5_dp*length - radius)
      case default
         h = 0.0_dp
      end select
   end function particle_half_segment

   !> Volume (3-D) or area (2-D) of one particle's true shape [m^3 or m^2]:
   !> cylinder pi R^2 L / rectangle 2 R L; sphere 4/3 pi R^3 / disk pi R^2;
   !> spheroid 4/3 pi a b^2 / ellipse pi a b with a = L/2, b = R.
   elemental function particle_volume(dim, shape, radius, length) result(vol)
      integer(ip), intent(in) :: dim, shape
      real(dp), intent(in) :: radius, length
      real(dp) :: vol
      real(dp), parameter :: pi = acos(-1.0_dp)
      if (dim == 2) then
         select case (shape)
         case (FOLD_FIBRE)
            vol = 2.0_dp*radius*length
         case (FOLD_SPHEROID)
            vol = pi*0.5_dp*length*radius
         case default
            vol = pi*radius**2
         end select
      else
         select case (shape)
         case (FOLD_FIBRE)
            vol = pi*radius**2*length
         case (FOLD_SPHEROID)
            vol = 4.0_dp/3.0_dp*pi*0.5_dp*length*radius**2
         case default
            vol = 4.0_dp/3.0_dp*pi*radius**3
         end select
      end if
   end function particle_volume

end module fold_particles
