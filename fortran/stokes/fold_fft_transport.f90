!> The FFT transport of the FFT Stokes solver: distributed-or-not real-to-complex FFTs
!> behind one abstract type (fft_transport_t). "Backend" names a Stokes solver
!> (fold_stokes_solver); a transport is what the FFT-based solvers transform with.
!>
!> The Stokes solver does its real-space arithmetic on the rank-local slab of a
!> padded real array r(nxp, nl(2), nl(3)) and its Fourier-space arithmetic on the
!> rank-local part of the half spectrum c(nsl(1), nsl(2), nsl(3)), nxp = 2 (nx/2 + 1),
!> nsl(1) = nxh = nx/2 + 1 (FFTW in-place r2c layout). The real-space slab is cut
!> along the slowest Fortran index that is > 1: z in 3-D, y in 2-D (then nl(3) = 1).
!> The spectral layout is described separately (nsl, soff, saxis): index d of a
!> spectral array runs over the global wavenumber axis saxis(d) from offset soff(d).
!> The serial transport and the 2-D MPI transport keep the real-space order
!> (saxis = [1, 2, 3]); the 3-D MPI transport leaves the spectrum transposed
!> (c(nxh, n3, local n2), saxis = [1, 3, 2], y distributed), which saves one global
!> transpose per transform (docs/physics.md#parallel-scaling-of-the-slab-decomposition).
!> Every Fourier-space loop of the solver is pointwise in the mode and reads its
!> wavenumbers from this map, so it never sees the order. A serial transport
!> (fold_fft_serial, in the core library that the Python extensions link) owns
!> the whole grid; an FFTW-MPI transport (fold_fft_mpi, executable only) owns one
!> slab and sums over ranks. Serial and parallel runs share every line of numerics.
module fold_fft_transport
   use, intrinsic :: iso_c_binding
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_check, only: check_dim
   implicit none
   private

   include 'fftw3.f03'

   !> One FFTW-aligned field usable for in-place transforms: the same memory seen
   !> as a padded real array and as a half spectrum, in double precision (r, c) and,
   !> on the first half of the same memory, in single precision (rs, cs; the
   !> single-precision transforms). The single views share the double ones' storage, so
   !> a field holds either, never both.
   type, public :: fft_field_t
      type(c_ptr) :: mem = c_null_ptr
      !> Real view (nxp, nl(2), nl(3)); only r(1:nx, :, :) is data, the rest padding
      real(dp), pointer, contiguous :: r(:, :, :) => null()
      !> Complex view (nsl(1), nsl(2), nsl(3)) of the transport (spectral layout)
      complex(dp), pointer, contiguous :: c(:, :, :) => null()
      !> Single-precision real view, same shape as r
      real(c_float), pointer, contiguous :: rs(:, :, :) => null()
      !> Single-precision complex view, same shape as c
      complex(c_float_complex), pointer, contiguous :: cs(:, :, :) => null()
   end type fft_field_t

   !> Abstract FFT engine of a fixed grid (global sizes n, local slab nl/off).
   type, abstract, public :: fft_transport_t
      !> Spatial dimension (2 or 3)
      integer(ip) :: dim = 3
      !> Global grid sizes (n(3) = 1 in 2-D)
      integer(ip) :: n(3) = 1
      !> Local extents of the real-space slab (first one: nx data of the nxp padded)
      integer(ip) :: nl(3) = 1
      !> Global 0-based offset of the local real-space slab in each direction
      integer(ip) :: off(3) = 0
      !> Local extents of the spectral arrays c(nsl(1), nsl(2), nsl(3)), nsl(1) = nxh
      integer(ip) :: nsl(3) = 1
      !> Global 0-based wavenumber offset along each spectral array index
      integer(ip) :: soff(3) = 0
      !> Global axis (1 x, 2 y, 3 z) that each spectral array index runs over
      integer(ip) :: saxis(3) = [1, 2, 3]
      !> Padded real leading extent 2 (nx/2 + 1) and spectral one nx/2 + 1
      integer(ip) :: nxp = 2, nxh = 1
      !> Number of complex numbers to allocate per field (FFTW-MPI may ask for more than the slab)
      integer(i8) :: alloc_complex = 1
      !> Rank of this process and number of ranks
      integer :: rank = 0, nranks = 1
      !> In-place r2c/c2r plans of the grid (serial or FFTW-MPI)
      type(c_ptr) :: fwd = c_null_ptr, bwd = c_null_ptr
      !> Single-precision (fftwf) plans, made by plan_single only
      type(c_ptr) :: fwd_sp = c_null_ptr, bwd_sp = c_null_ptr
   contains
      !> In-place transform of a field by the plan of one direction and precision,
      !> unnormalised: forward real view -> complex view, backward complex view -> real
      !> view (destroys the input); single: the fftwf plans on rs/cs (after plan_single)
      procedure(transform_iface), deferred :: transform
      !> In-place double-precision forward / backward transform (transform)
      procedure :: r2c => transport_r2c
      procedure :: c2r => transport_c2r
      !> Make the single-precision plans (fftwf) of the grid; once, before a single transform
      procedure(plan_single_iface), deferred :: plan_single
      !> Sum an array over all ranks (in place)
      procedure(reduce_iface), deferred :: sum_all
      !> Maximum of an array over all ranks (in place)
      procedure(reduce_iface), deferred :: max_all
      !> Boundary planes of the slab ring (last axis, periodic): lo <- the previous rank's
      !> last, hi <- the next rank's first (one rank: its own last and first)
      procedure(halo_iface), deferred :: z_halo
      !> Release the FFTW plans
      procedure(destroy_iface), deferred :: destroy
      !> Allocate an aligned field of this grid
      procedure :: alloc_field => transport_alloc_field
      !> f <- r2c(c eta c2r(f)): back to real space, pointwise product, forward again
      !> (the viscosity step of the Stokes operator). A serial override that split the
      !> 3-D transforms (slow axes over the field, then x rows and the product plane
      !> by plane in cache) was measured 5-10 % slower than FFTW's own 3-D plans at
      !> 64^3 and 128^3, so every transport uses this reference.
      procedure :: c2r_scale_r2c => transport_c2r_scale_r2c
   end type fft_transport_t

   abstract interface
      subroutine transform_iface(self, f, forward, single)
         import :: fft_transport_t, fft_field_t
         class(fft_transport_t), intent(inout) :: self
         type(fft_field_t), intent(inout) :: f
         logical, intent(in) :: forward, single
      end subroutine transform_iface
      subroutine plan_single_iface(self, effort, stat, errmsg)
         import :: fft_transport_t, msg_len
         class(fft_transport_t), intent(inout) :: self
         integer, intent(in) :: effort
         integer, intent(out) :: stat
         character(len=msg_len), intent(out) :: errmsg
      end subroutine plan_single_iface
      subroutine reduce_iface(self, x)
         import :: fft_transport_t, dp
         class(fft_transport_t), intent(in) :: self
         real(dp), intent(inout) :: x(:)
      end subroutine reduce_iface
      subroutine halo_iface(self, n, first, last, lo, hi)
         import :: fft_transport_t, dp, i8
         class(fft_transport_t), intent(in) :: self
         integer(i8), intent(in) :: n
         real(dp), intent(in) :: first(n), last(n)
         real(dp), intent(out) :: lo(n), hi(n)
      end subroutine halo_iface
      subroutine destroy_iface(self)
         import :: fft_transport_t
         class(fft_transport_t), intent(inout) :: self
      end subroutine destroy_iface
   end interface

   public :: grid_check, plans_free, single_plans_check, field_free, fields_free, FOLD_PLAN_ESTIMATE, FOLD_PLAN_MEASURE, plan_flag, scale_rows, spectral_natural

   !> FFTW planning effort: FFTW_ESTIMATE (instant) or FFTW_MEASURE (seconds, faster transforms)
   integer, parameter :: FOLD_PLAN_ESTIMATE = 0, FOLD_PLAN_MEASURE = 1

contains

   !> FOLD_INPUT_ERROR unless dim is 2 or 3 and every grid size n(1:dim) >= 2; the
   !> message starts with who (the creating routine).
   subroutine grid_check(who, dim, n, stat, errmsg)
      character(len=*), intent(in) :: who
      integer(ip), intent(in) :: dim, n(3)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call check_dim(dim, who, stat, errmsg)
      if (stat /= FOLD_OK .or. all(n(1:dim) >= 2)) return
      stat = FOLD_INPUT_ERROR
      write (errmsg, '(a,3(1x,i0))') who//": every grid size must be >= 2, got", n(1:dim)
   end subroutine grid_check

   !> Allocate an FFTW-aligned field (every field of a grid has the same
   !> alignment, which FFTW's new-array execute functions require).
   subroutine transport_alloc_field(self, f)
      class(fft_transport_t), intent(in) :: self
      type(fft_field_t), intent(inout) :: f
      call field_free(f)
      f%mem = fftw_alloc_complex(int(max(self%alloc_complex, 1_i8), c_size_t))
      call c_f_pointer(f%mem, f%r, [self%nxp, self%nl(2), self%nl(3)])
      call c_f_pointer(f%mem, f%c, self%nsl)
      call c_f_pointer(f%mem, f%rs, [self%nxp, self%nl(2), self%nl(3)])
      call c_f_pointer(f%mem, f%cs, self%nsl)
      f%r = 0.0_dp
   end subroutine transport_alloc_field

   subroutine transport_r2c(self, f)
      class(fft_transport_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      call self%transform(f, .true., .false.)
   end subroutine transport_r2c

   subroutine transport_c2r(self, f)
      class(fft_transport_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      call self%transform(f, .false., .false.)
   end subroutine transport_c2r

   !> Unfused reference: c2r, w = c eta w on the nx data columns, r2c.
   subroutine transport_c2r_scale_r2c(self, f, c, eta)
      class(fft_transport_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      !> Constant factor [-] and field (padded real layout) of the product
      real(dp), intent(in) :: c
      type(fft_field_t), intent(in) :: eta
      call self%c2r(f)
      call scale_rows(self%n(1), self%nxp, self%nl(2)*self%nl(3), c, eta%r, f%r)
      call self%r2c(f)
   end subroutine transport_c2r_scale_r2c

   !> w(1:nx, :) = c eta(1:nx, :) w(1:nx, :) on padded real rows (nxp, nrows).
   subroutine scale_rows(nx, nxp, nrows, c, eta, w)
      integer(ip), intent(in) :: nx, nxp, nrows
      real(dp), intent(in) :: c, eta(nxp, nrows)
      real(dp), intent(inout) :: w(nxp, nrows)
      integer(ip) :: i, r
      do r = 1, nrows
         do i = 1, nx
            w(i, r) = (c*eta(i, r))*w(i, r)
         end do
      end do
   end subroutine scale_rows

   !> Destroy the plans of a transport (FFTW-MPI plans too: fftw_destroy_plan frees both).
   subroutine plans_free(self)
      class(fft_transport_t), intent(inout) :: self
      if (c_associated(self%fwd)) call fftw_destroy_plan(self%fwd)
      if (c_associated(self%bwd)) call fftw_destroy_plan(self%bwd)
      if (c_associated(self%fwd_sp)) call fftwf_destroy_plan(self%fwd_sp)
      if (c_associated(self%bwd_sp)) call fftwf_destroy_plan(self%bwd_sp)
      self%fwd = c_null_ptr
      self%bwd = c_null_ptr
      self%fwd_sp = c_null_ptr
      self%bwd_sp = c_null_ptr
   end subroutine plans_free

   !> The status of plan_single: FOLD_INPUT_ERROR with "<who> could not make the
   !> single-precision plans" unless both fftwf plans exist.
   subroutine single_plans_check(self, who, stat, errmsg)
      class(fft_transport_t), intent(in) :: self
      !> Transport and library in the message ("fft_serial: FFTW")
      character(len=*), intent(in) :: who
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_OK
      errmsg = ""
      if (c_associated(self%fwd_sp) .and. c_associated(self%bwd_sp)) return
      stat = FOLD_INPUT_ERROR
      errmsg = who//" could not make the single-precision plans"
   end subroutine single_plans_check

   !> Free a field (no-op when not allocated).
   subroutine field_free(f)
      type(fft_field_t), intent(inout) :: f
      if (c_associated(f%mem)) call fftw_free(f%mem)
      f%mem = c_null_ptr
      f%r => null()
      f%c => null()
      f%rs => null()
      f%cs => null()
   end subroutine field_free

   !> Free every field of an array and the array (no-op when not allocated).
   subroutine fields_free(f)
      type(fft_field_t), allocatable, intent(inout) :: f(:)
      integer :: c
      if (.not. allocated(f)) return
      do c = 1, size(f)
         call field_free(f(c))
      end do
      deallocate (f)
   end subroutine fields_free

   !> Spectral layout in the real-space order: c(nxh, nl(2), nl(3)) (serial, 2-D MPI).
   subroutine spectral_natural(self)
      class(fft_transport_t), intent(inout) :: self
      self%nsl = [self%nxh, self%nl(2), self%nl(3)]
      self%soff = [0_ip, self%off(2), self%off(3)]
      self%saxis = [1_ip, 2_ip, 3_ip]
   end subroutine spectral_natural

   !> FFTW planner flag for a planning-effort code.
   pure function plan_flag(effort) result(flag)
      integer, intent(in) :: effort
      integer :: flag
      if (effort == FOLD_PLAN_MEASURE) then
         flag = FFTW_MEASURE
      else
         flag = FFTW_ESTIMATE
      end if
   end function plan_flag

end module fold_fft_transport
