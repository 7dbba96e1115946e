!> Stack smoke test: FFTW 3 Fortran 2003 interface, real-to-complex 3-D transform
!> of a single Fourier mode lands in the right bin with amplitude N/2, and the
!> round trip returns the input times N (FFTW transforms are unnormalised).
program smoke_fftw
   use, intrinsic :: iso_c_binding
   implicit none
   include 'fftw3.f03'
   integer, parameter :: n1 = 12, n2 = 10, n3 = 8
   real(c_double), allocatable :: f(:, :, :), g(:, :, :)
   complex(c_double_complex), allocatable :: fh(:, :, :)
   type(c_ptr) :: fwd, bwd
   real(c_double), parameter :: pi = acos(-1.0_c_double)
   integer :: i, j, k
   real(c_double) :: err
   allocate (f(n1, n2, n3), g(n1, n2, n3), fh(n1/2 + 1, n2, n3))
   ! column-major a(n1,n2,n3) is FFTW's row-major (n3,n2,n1): pass sizes reversed
   fwd = fftw_plan_dft_r2c_3d(n3, n2, n1, f, fh, FFTW_ESTIMATE)
   bwd = fftw_plan_dft_c2r_3d(n3, n2, n1, fh, g, FFTW_ESTIMATE)
   do k = 1, n3
      do j = 1, n2
         do i = 1, n1
            f(i, j, k) = cos(2*pi*(2*(i - 1)/real(n1, c_double) + 3*(j - 1)/real(n2, c_double)))
         end do
      end do
   end do
   call fftw_execute_dft_r2c(fwd, f, fh)
   ! mode (2, 3, 0): 1-based bin (3, 4, 1); amplitude n1*n2*n3/2
   err = abs(fh(3, 4, 1) - cmplx(n1*n2*n3/2.0_c_double, 0.0_c_double, c_double_complex))
   fh(3, 4, 1) = 0
   err = max(err, maxval(abs(fh))/(n1*n2*n3))
   call fftw_execute_dft_r2c(fwd, f, fh)
   call fftw_execute_dft_c2r(bwd, fh, g)
   err = max(err, maxval(abs(g/(n1*n2*n3) - f)))
   call fftw_destroy_plan(fwd)
   call fftw_destroy_plan(bwd)
   if (err > 1.0e-9_c_double) then
      print '(a,es10.3)', "smoke_fftw: error ", err
      error stop 1
   end if
   print '(a,es10.3)', "smoke_fftw: ok, max error ", err
end program smoke_fftw
