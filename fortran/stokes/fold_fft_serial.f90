!> Serial FFTW backend: the whole grid on one process (used by the Python
!> extension, the tests and single-rank runs).
module fold_fft_serial
   use, intrinsic :: iso_c_binding
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_fft_backend, only: fft_backend_t, fft_field_t, field_free, plan_flag, scale_rows
   implicit none
   private

   include 'fftw3.f03'

   !> Serial in-place r2c/c2r plans of one grid, and the split plans of the fused
   !> c2r -> product -> r2c: complex transforms over the slow axes (y, z) for every
   !> x wavenumber, and real transforms along x for the rows of one slow-axis plane.
   type, extends(fft_backend_t), public :: fft_serial_t
      type(c_ptr) :: fwd = c_null_ptr, bwd = c_null_ptr
      type(c_ptr) :: slow_fwd = c_null_ptr, slow_bwd = c_null_ptr, rows_r2c = c_null_ptr, rows_c2r = c_null_ptr
   contains
      procedure :: r2c => serial_r2c
      procedure :: c2r => serial_c2r
      procedure :: c2r_scale_r2c => serial_c2r_scale_r2c
      procedure :: sum_all => serial_reduce
      procedure :: max_all => serial_reduce
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
      type(fft_field_t) :: scratch
      integer(c_int) :: nxh, nxp, n2, n3, nx, rows_flag

      stat = FOLD_OK
      errmsg = ""
      if (dim /= 2 .and. dim /= 3) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0)') "fft_serial_create: dim must be 2 or 3, got ", dim
         return
      end if
      if (any(n(1:dim) < 2)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,3(1x,i0))') "fft_serial_create: every grid size must be >= 2, got", n(1:dim)
         return
      end if
      call serial_destroy(self)
      self%dim = dim
      self%n = 1
      self%n(1:dim) = n(1:dim)
      self%nl = self%n
      self%off = 0
      self%nxh = self%n(1)/2 + 1
      self%nxp = 2*self%nxh
      self%alloc_complex = int(self%nxh, i8)*self%n(2)*self%n(3)
      self%rank = 0
      self%nranks = 1
      call self%alloc_field(scratch)
      ! Column-major a(nx, ny, nz) is FFTW's row-major (nz, ny, nx): sizes reversed.
      if (dim == 3) then
         self%fwd = fftw_plan_dft_r2c_3d(self%n(3), self%n(2), self%n(1), scratch%r, scratch%c, plan_flag(effort))
         self%bwd = fftw_plan_dft_c2r_3d(self%n(3), self%n(2), self%n(1), scratch%c, scratch%r, plan_flag(effort))
      else
         self%fwd = fftw_plan_dft_r2c_2d(self%n(2), self%n(1), scratch%r, scratch%c, plan_flag(effort))
         self%bwd = fftw_plan_dft_c2r_2d(self%n(2), self%n(1), scratch%c, scratch%r, plan_flag(effort))
      end if
      ! Split plans (c2r_scale_r2c). Slow axes: complex transforms of stride nxh, one per
      ! x wavenumber. Rows: the n2 rows of one z-plane (3-D) or the whole 2-D field.
      nx = int(self%n(1), c_int)
      nxh = int(self%nxh, c_int)
      nxp = int(self%nxp, c_int)
      n2 = int(self%n(2), c_int)
      n3 = int(self%n(3), c_int)
      if (dim == 3) then
         self%slow_bwd = fftw_plan_many_dft(2, [n3, n2], nxh, scratch%c, [n3, n2], nxh, 1, scratch%c, [n3, n2], nxh, 1, &
                                            FFTW_BACKWARD, plan_flag(effort))
         self%slow_fwd = fftw_plan_many_dft(2, [n3, n2], nxh, scratch%c, [n3, n2], nxh, 1, scratch%c, [n3, n2], nxh, 1, &
                                            FFTW_FORWARD, plan_flag(effort))
      else
         self%slow_bwd = fftw_plan_many_dft(1, [n2], nxh, scratch%c, [n2], nxh, 1, scratch%c, [n2], nxh, 1, &
                                            FFTW_BACKWARD, plan_flag(effort))
         self%slow_fwd = fftw_plan_many_dft(1, [n2], nxh, scratch%c, [n2], nxh, 1, scratch%c, [n2], nxh, 1, &
                                            FFTW_FORWARD, plan_flag(effort))
      end if
      ! The row plans are executed on every z-plane: unless each plane starts at the
      ! field's alignment (64 bytes covers any SIMD FFTW uses), plan them unaligned.
      rows_flag = plan_flag(effort)
      if (mod(int(nxp, i8)*n2*8_i8, 64_i8) /= 0) rows_flag = ior(rows_flag, FFTW_UNALIGNED)
      self%rows_c2r = fftw_plan_many_dft_c2r(1, [nx], n2, scratch%c, [nxh], 1, nxh, scratch%r, [nxp], 1, nxp, rows_flag)
      self%rows_r2c = fftw_plan_many_dft_r2c(1, [nx], n2, scratch%r, [nxp], 1, nxp, scratch%c, [nxh], 1, nxh, rows_flag)
      call field_free(scratch)
      if (.not. (c_associated(self%fwd) .and. c_associated(self%bwd) .and. c_associated(self%slow_fwd) .and. &
                 c_associated(self%slow_bwd) .and. c_associated(self%rows_c2r) .and. c_associated(self%rows_r2c))) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,3(1x,i0))') "fft_serial_create: FFTW could not plan the grid", self%n(1:dim)
      end if
   end subroutine fft_serial_create

   subroutine serial_r2c(self, f)
      class(fft_serial_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      call fftw_execute_dft_r2c(self%fwd, f%r, f%c)
   end subroutine serial_r2c

   subroutine serial_c2r(self, f)
      class(fft_serial_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      call fftw_execute_dft_c2r(self%bwd, f%c, f%r)
   end subroutine serial_c2r

   !> Fused viscosity step: inverse transform over the slow axes for the whole field,
   !> then plane by plane (in cache) the inverse x transform of the rows, the product
   !> c eta w, and the forward x transform, then the forward slow-axis transform. Same
   !> result as c2r, product, r2c (to round-off) with two sweeps of the field fewer.
   subroutine serial_c2r_scale_r2c(self, f, c, eta)
      class(fft_serial_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      real(dp), intent(in) :: c
      type(fft_field_t), intent(in) :: eta
      integer(ip) :: k
      complex(dp), pointer, contiguous :: cp(:)
      real(dp), pointer, contiguous :: rp(:), ep(:)
      call fftw_execute_dft(self%slow_bwd, f%c, f%c)
      ! 1-D views of one plane: never a copy, the in-place row plans must see the
      ! field's own memory
      do k = 1, self%n(3)
         call c_f_pointer(c_loc(f%c(1, 1, k)), cp, [self%nxh*self%n(2)])
         call c_f_pointer(c_loc(f%r(1, 1, k)), rp, [self%nxp*self%n(2)])
         call c_f_pointer(c_loc(eta%r(1, 1, k)), ep, [self%nxp*self%n(2)])
         call fftw_execute_dft_c2r(self%rows_c2r, cp, rp)
         call scale_rows(self%n(1), self%nxp, self%n(2), c, ep, rp)
         call fftw_execute_dft_r2c(self%rows_r2c, rp, cp)
      end do
      call fftw_execute_dft(self%slow_fwd, f%c, f%c)
   end subroutine serial_c2r_scale_r2c

   !> One process: a global sum or maximum is the local value.
   subroutine serial_reduce(self, x)
      class(fft_serial_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)
   end subroutine serial_reduce

   subroutine serial_destroy(self)
      class(fft_serial_t), intent(inout) :: self
      if (c_associated(self%fwd)) call fftw_destroy_plan(self%fwd)
      if (c_associated(self%bwd)) call fftw_destroy_plan(self%bwd)
      if (c_associated(self%slow_fwd)) call fftw_destroy_plan(self%slow_fwd)
      if (c_associated(self%slow_bwd)) call fftw_destroy_plan(self%slow_bwd)
      if (c_associated(self%rows_c2r)) call fftw_destroy_plan(self%rows_c2r)
      if (c_associated(self%rows_r2c)) call fftw_destroy_plan(self%rows_r2c)
      self%fwd = c_null_ptr
      self%bwd = c_null_ptr
      self%slow_fwd = c_null_ptr
      self%slow_bwd = c_null_ptr
      self%rows_c2r = c_null_ptr
      self%rows_r2c = c_null_ptr
   end subroutine serial_destroy

end module fold_fft_serial
