!> Serial FFTW transport: the whole grid on one process (used by the Python
!> extension, the tests and single-rank runs).
module fold_fft_serial
   use, intrinsic :: iso_c_binding
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK
   use fold_fft_transport, only: fft_transport_t, fft_field_t, field_free, plans_free, plan_flag, spectral_natural, &
                                 single_plans_check, grid_check
   implicit none
   private

   include 'fftw3.f03'

   !> Serial in-place r2c/c2r plans of one grid.
   type, extends(fft_transport_t), public :: fft_serial_t
   contains
      procedure :: transform => serial_transform
      procedure :: plan_single => serial_plan_single
      procedure :: sum_all => serial_reduce
      procedure :: max_all => serial_reduce
      procedure :: z_halo => serial_z_halo
      procedure :: destroy => serial_destroy
   end type fft_serial_t

   public :: fft_serial_create

contains

   !> Make the plans of an nx x ny (x nz) grid once; effort FOLD_PLAN_ESTIMATE/MEASURE.
   subroutine fft_serial_create(self, dim, n, effort, stat, errmsg)
      type(fft_serial_t), intent(inout) :: self
      !> Spatial dimension (2 or 3)
      integer(ip), intent(in) :: dim
      !> Grid sizes (n(3) ignored in 2-D)
      integer(ip), intent(in) :: n(3)
      !> Planning effort code
      integer, intent(in) :: effort
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      call grid_check("fft_serial_create", dim, n, stat, errmsg)
      if (stat /= FOLD_OK) return
      call serial_destroy(self)
      self%dim = dim
      self%n = 1
      self%n(1:dim) = n(1:dim)
      self%nl = self%n
      self%off = 0
      self%nxh = self%n(1)/2 + 1
      self%nxp = 2*self%nxh
      call spectral_natural(self)
      self%alloc_complex = int(self%nxh, i8)*self%n(2)*self%n(3)
      self%rank = 0
      self%nranks = 1
      call serial_plans(self, effort, .false.)
   end subroutine fft_serial_create

   !> The fftwf plans of the grid (same layout as the double ones, on the first half
   !> of a field's memory: fft_field_t%rs/cs).
   subroutine serial_plan_single(self, effort, stat, errmsg)
      class(fft_serial_t), intent(inout) :: self
      integer, intent(in) :: effort
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      if (.not. c_associated(self%fwd_sp)) call serial_plans(self, effort, .true.)
      call single_plans_check(self, "fft_serial: FFTW", stat, errmsg)
   end subroutine serial_plan_single

   !> Make the in-place r2c/c2r plans of the grid in one precision (single: fftwf on the
   !> rs/cs views) on a scratch field. Column-major a(nx, ny, nz) is FFTW's row-major
   !> (nz, ny, nx): sizes reversed.
   subroutine serial_plans(self, effort, single)
      class(fft_serial_t), intent(inout) :: self
      integer, intent(in) :: effort
      logical, intent(in) :: single
      type(fft_field_t) :: scratch
      integer :: flag
      flag = plan_flag(effort)
      call self%alloc_field(scratch)
      associate (n => self%n)
         if (single .and. self%dim == 3) then
            self%fwd_sp = fftwf_plan_dft_r2c_3d(n(3), n(2), n(1), scratch%rs, scratch%cs, flag)
            self%bwd_sp = fftwf_plan_dft_c2r_3d(n(3), n(2), n(1), scratch%cs, scratch%rs, flag)
         else if (single) then
            self%fwd_sp = fftwf_plan_dft_r2c_2d(n(2), n(1), scratch%rs, scratch%cs, flag)
            self%bwd_sp = fftwf_plan_dft_c2r_2d(n(2), n(1), scratch%cs, scratch%rs, flag)
         else if (self%dim == 3) then
            self%fwd = fftw_plan_dft_r2c_3d(n(3), n(2), n(1), scratch%r, scratch%c, flag)
            self%bwd = fftw_plan_dft_c2r_3d(n(3), n(2), n(1), scratch%c, scratch%r, flag)
         else
            self%fwd = fftw_plan_dft_r2c_2d(n(2), n(1), scratch%r, scratch%c, flag)
            self%bwd = fftw_plan_dft_c2r_2d(n(2), n(1), scratch%c, scratch%r, flag)
         end if
      end associate
      call field_free(scratch)
   end subroutine serial_plans

   subroutine serial_transform(self, f, forward, single)
      class(fft_serial_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      logical, intent(in) :: forward, single
      if (single) then
         if (forward) then
            call fftwf_execute_dft_r2c(self%fwd_sp, f%rs, f%cs)
         else
            call fftwf_execute_dft_c2r(self%bwd_sp, f%cs, f%rs)
         end if
      else if (forward) then
         call fftw_execute_dft_r2c(self%fwd, f%r, f%c)
      else
         call fftw_execute_dft_c2r(self%bwd, f%c, f%r)
      end if
   end subroutine serial_transform

   !> One process: a global sum or maximum is the local value.
   subroutine serial_reduce(self, x)
      class(fft_serial_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)
   end subroutine serial_reduce

   subroutine serial_destroy(self)
      class(fft_serial_t), intent(inout) :: self
      call plans_free(self)
   end subroutine serial_destroy

   !> One slab closes the ring on itself.
   subroutine serial_z_halo(self, n, first, last, lo, hi)
      class(fft_serial_t), intent(in) :: self
      integer(i8), intent(in) :: n
      real(dp), intent(in) :: first(n), last(n)
      real(dp), intent(out) :: lo(n), hi(n)
      lo = last
      hi = first
   end subroutine serial_z_halo

end module fold_fft_serial
