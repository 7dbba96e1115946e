!> Uniform grid on the periodic cell, following the (Lees-Edwards) skewed lattice.
!>
!> The cell is the parallelepiped spanned by the lattice basis A = [a1 a2 a3]
!> (columns). Under simple shear a1 = (Lx,0,0), a2 = (s,Ly,0), a3 = (0,0,Lz) with
!> the wrapped offset s (docs/physics.md#lees-edwards-skewed-lattice); when s wraps the
!> cell module re-chooses the basis and the grid simply takes the new A (Stokes flow has no memory, so
!> every step may rebuild the grid; the FFT plans only depend on the counts n).
!> Voxel m = (m1, m2, m3), 0 <= m_j < n_j, is the parallelepiped with corner
!> A (m/n) and centre A ((m + 1/2)/n); the characteristic function chi and the
!> viscosity live at the voxel centres. In 2-D the third row/column of A is e3
!> and n(3) = 1.
module fold_grid
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_mat3, only: adjugate3
   use fold_check, only: check_dim
   implicit none
   private

   !> Grid counts, local slab and current lattice of the periodic cell.
   type, public :: grid_t
      !> Spatial dimension (2 or 3)
      integer(ip) :: dim = 3
      !> Global number of voxels along each lattice vector (n(3) = 1 in 2-D)
      integer(ip) :: n(3) = 1
      !> Local slab extents and 0-based offsets (whole grid in serial)
      integer(ip) :: nl(3) = 1, off(3) = 0
      !> Lattice basis, columns a1, a2, a3 [m]
      real(dp) :: A(3, 3) = 0.0_dp
      !> Inverse of A [1/m]
      real(dp) :: Ainv(3, 3) = 0.0_dp
      !> Cell volume |det A| [m^3] (area in 2-D) and voxel volume [m^3]
      real(dp) :: volume = 0.0_dp, dv = 0.0_dp
      !> Voxel size dv^(1/dim) [m]
      real(dp) :: h = 0.0_dp
      !> Half of the longest voxel diagonal [m]
      real(dp) :: half_diag = 0.0_dp
   end type grid_t

   public :: grid_init, grid_set_lattice, grid_point, grid_total, shear_lattice

contains

   !> Set the counts and the rank-local slab (nl, off) of a grid.
   subroutine grid_init(grid, dim, n, nl, off, stat, errmsg)
      type(grid_t), intent(inout) :: grid
      !> Spatial dimension (2 or 3)
      integer(ip), intent(in) :: dim
      !> Global voxel counts (n(3) ignored in 2-D)
      integer(ip), intent(in) :: n(3)
      !> Local slab extents and global 0-based offsets
      integer(ip), intent(in) :: nl(3), off(3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      call check_dim(dim, "grid_init", stat, errmsg)
      if (stat /= FOLD_OK) return
      stat = FOLD_INPUT_ERROR
      if (any(n(1:dim) < 2)) then
         write (errmsg, '(a,3(1x,i0))') "grid_init: grid counts must be >= 2, got", n(1:dim)
         return
      end if
      grid%dim = dim
      grid%n = 1
      grid%n(1:dim) = n(1:dim)
      grid%nl = 1
      grid%off = 0
      grid%nl(1:dim) = nl(1:dim)
      grid%off(1:dim) = off(1:dim)
      if (any(grid%nl < 0) .or. any(grid%off < 0) .or. any(grid%off + grid%nl > grid%n)) then
         write (errmsg, '(a,3(1x,i0),a,3(1x,i0))') "grid_init: local slab outside the grid: nl", grid%nl, &
            ", off", grid%off
         return
      end if
      stat = FOLD_OK
   end subroutine grid_init

   !> Set the lattice basis (columns a1, a2[, a3]); it must be right-handed.
   subroutine grid_set_lattice(grid, A, stat, errmsg)
      type(grid_t), intent(inout) :: grid
      !> Lattice basis as columns [m]; in 2-D only A(1:2, 1:2) is read
      real(dp), intent(in) :: A(3, 3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp) :: det, corner(3), d
      integer :: s1, s2, s3

      stat = FOLD_OK
      errmsg = ""
      grid%A = 0.0_dp
      if (grid%dim == 2) then
         grid%A(1:2, 1:2) = A(1:2, 1:2)
         grid%A(3, 3) = 1.0_dp
      else
         grid%A = A
      end if
      det = det3(grid%A)
      if (.not. (det > 0.0_dp)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,es10.3)') "grid_set_lattice: lattice basis must be right-handed with det A > 0, got ", det
         return
      end if
      grid%Ainv = inv3(grid%A, det)
      grid%volume = det
      grid%dv = det/real(product(grid%n), dp)
      grid%h = grid%dv**(1.0_dp/grid%dim)
      grid%half_diag = 0.0_dp
      do s1 = -1, 1, 2
         do s2 = -1, 1, 2
            do s3 = -1, 1, 2
               corner = matmul(grid%A, [s1, s2, s3]/real(2*grid%n, dp))
               if (grid%dim == 2) corner(3) = 0.0_dp
               d = norm2(corner)
               grid%half_diag = max(grid%half_diag, d)
            end do
         end do
      end do
   end subroutine grid_set_lattice

   !> Physical position A (m + shift)/n of (possibly unwrapped) voxel index m;
   !> shift = 1/2 gives the voxel centre, 0 the lower corner [m].
   pure function grid_point(grid, m, shift) result(x)
      type(grid_t), intent(in) :: grid
      integer(ip), intent(in) :: m(3)
      real(dp), intent(in) :: shift
      real(dp) :: x(3)
      x = matmul(grid%A, (real(m, dp) + shift)/real(grid%n, dp))
      if (grid%dim == 2) x(3) = 0.0_dp
   end function grid_point

   !> Total number of voxels of the global grid.
   pure function grid_total(grid) result(nt)
      type(grid_t), intent(in) :: grid
      integer(i8) :: nt
      nt = int(grid%n(1), i8)*grid%n(2)*grid%n(3)
   end function grid_total

   !> Lees-Edwards lattice of a box lengths L sheared in x along y with offset s:
   !> a1 = (Lx,0,0), a2 = (s,Ly,0), a3 = (0,0,Lz) (docs/physics.md#lees-edwards-skewed-lattice).
   pure function shear_lattice(lengths, s) result(A)
      real(dp), intent(in) :: lengths(3), s
      real(dp) :: A(3, 3)
      A = 0.0_dp
      A(1, 1) = lengths(1)
      A(1, 2) = s
      A(2, 2) = lengths(2)
      A(3, 3) = lengths(3)
   end function shear_lattice

   pure function det3(a) result(d)
      real(dp), intent(in) :: a(3, 3)
      real(dp) :: d
      d = a(1, 1)*(a(2, 2)*a(3, 3) - a(2, 3)*a(3, 2)) - a(1, 2)*(a(2, 1)*a(3, 3) - a(2, 3)*a(3, 1)) &
          + a(1, 3)*(a(2, 1)*a(3, 2) - a(2, 2)*a(3, 1))
   end function det3

   pure function inv3(a, d) result(b)
      real(dp), intent(in) :: a(3, 3), d
      real(dp) :: b(3, 3)
      b = adjugate3(a)
      b = b/d
   end function inv3

end module fold_grid
