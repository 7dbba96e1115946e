!> The real-space stencil form of the FFT solver's CG operator
!> (stencil_force in fortran/stokes/fold_cg_kernels.f90.in: 3 + 3 transforms per iteration) is the same
!> operator as the spectral form (fold_stokes_fft stokes_fft_apply: 6 + 6 transforms),
!> through the factory (serial FFTW on one rank, FFTW-MPI slabs with the transposed
!> spectrum on two), on a sheared non-cubic lattice with a sphere of partial-volume
!> boundary, on odd and even grids, for a random divergence-free u:
!>  * A u from the CG's passes (stokes_fft_apply_cg) against stokes_fft_apply. Each form
!>    computes A u = P B^H 2 eta B u through two transforms per field (normwise relative
!>    error <= log2 N eta_F each, eta_F = 7 u: Higham 2002, Accuracy and Stability of
!>    Numerical Algorithms, thm 24.2, with sqrt(2) + gamma_4 per butterfly and accurate
!>    twiddles) and O(30) roundings of its local passes, all relative to norms bounded
!>    by ||B||^2 2 eta_max ||u||, so
!>        ||A_st u - A_sp u|| / ||A u|| <= 2 (14 log2 N + 30) u_p F,
!>        F = ||B||^2 2 eta_max ||u|| / ||A u||,
!>    ||B|| = max |kv| over the kept modes, u_p the unit round-off of the transforms'
!>    precision (the double one, and with fft_precision single the single one for the
!>    force's rounding and transform). F is evaluated for the test's u (norms of the half
!>    spectrum with its Hermitian weights), not read off the comparison;
!>  * the solve through the stencil form reaches the tolerance in the spectral
!>    operator's true residual (stokes_fft_true_residual) within 2 tol.
!> Run with mpirun -np 1 or 2 (meson suite 'stokes').
program test_stokes_stencil
   use mpi_f08
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_NOT_CONVERGED
   use fold_fft_transport, only: fft_field_t, field_free
   use fold_stokes_solver, only: stokes_solver_t, stokes_settings_t, FOLD_FFT_DOUBLE, FOLD_FFT_SINGLE
   use fold_stokes_fft, only: stokes_fft_t, stokes_fft_apply, stokes_fft_apply_cg, stokes_fft_project, &
                              stokes_fft_true_residual, FOLD_SINGLE_ROUNDOFF
   use stokes_test_check, only: check, ball_chi
   use stokes_test_solver, only: sheared_solver, mpi_test_start, mpi_test_end
   implicit none
   integer :: rank, failures

   call mpi_test_start("test_stokes_stencil", rank, failures)
   call compare([12_ip, 10_ip, 8_ip], 1.0e3_dp, FOLD_FFT_DOUBLE, failures)
   call compare([15_ip, 9_ip, 13_ip], 10.0_dp, FOLD_FFT_DOUBLE, failures)
   call compare([12_ip, 10_ip, 8_ip], 1.0e3_dp, FOLD_FFT_SINGLE, failures)
   call mpi_test_end(failures)

contains

   subroutine compare(n, kappa, precision, failures)
      integer(ip), intent(in) :: n(3), precision
      real(dp), intent(in) :: kappa
      integer, intent(inout) :: failures
      class(stokes_solver_t), allocatable :: s
      type(stokes_settings_t) :: set
      real(dp), allocatable :: chi(:, :, :)
      complex(dp), allocatable :: u(:, :, :, :), a_sp(:, :, :, :), a_st(:, :, :, :)
      type(fft_field_t) :: f
      real(dp) :: G(3, 3), red(2), err, bound, res, kmax(1), fac
      integer :: stat, c, j, k, seed_size
      integer, allocatable :: seed(:)
      character(len=msg_len) :: msg

      set%kappa = kappa
      set%tol = merge(1.0e-9_dp, 1.0e-4_dp, precision == FOLD_FFT_DOUBLE)
      set%max_iter = 5000
      set%warm_start = .false.
      set%fft_precision = precision
      call sheared_solver(set, n, s, failures)
      select type (s)
      type is (stokes_fft_t)
         ! a sphere of radius 0.3 of the cell with a one-voxel partial-volume ramp
         chi = ball_chi(n, s%grid%nl(2), s%grid%nl(3), s%grid%off(3), 0.5_dp)
         G = 0.0_dp
         G(1, 2) = 1.0_dp
         call s%solve(chi, G, stat, msg)
         call check(stat == FOLD_OK, "solve: "//trim(msg), failures)
         call check(s%stencil, "a sphere of 13 % of the cell is solved in the stencil form", failures)
         res = stokes_fft_true_residual(s)
         call check(res <= 2.0_dp*set%tol, "true residual <= 2 tol", failures)
         if (rank == 0) print '(a,3(1x,i0),a,i0,a,es9.2,a,i0,a,es9.2)', "grid", n, " precision ", precision, &
            " kappa ", kappa, ": iterations ", s%iterations, ", true residual ", res

         ! a random real corner field, its (Hermitian) transform, staggered and projected
         call random_seed(size=seed_size)
         allocate (seed(seed_size))
         seed = 12345 + 7*rank
         call random_seed(put=seed)
         allocate (u, mold=s%x)
         allocate (a_sp, a_st, mold=s%x)
         call s%fft%alloc_field(f)
         do c = 1, 3
            call random_number(f%r)
            f%r(n(1) + 1:, :, :) = 0.0_dp
            call s%fft%r2c(f)
            do k = 1, s%fft%nsl(3)
               do j = 1, s%fft%nsl(2)
                  u(:, j, k, c) = f%c(:, j, k)*s%ph1*s%ph23(j + (k - 1)*s%fft%nsl(2))
               end do
            end do
         end do
         call field_free(f)
         call stokes_fft_project(s, u)
         call stokes_fft_apply(s, u, a_sp)
         call stokes_fft_apply_cg(s, u, a_st)
         red = [weighted(s%wx, a_st - a_sp), weighted(s%wx, a_sp)]
         call s%sum_all(red)
         err = sqrt(red(1)/red(2))
         ! F = ||B||^2 2 eta_max ||u|| / ||A u||
         kmax = [maxval(sum(s%kv**2, dim=1))]
         call s%max_all(kmax)
         red = [weighted(s%wx, u), weighted(s%wx, a_sp)]
         call s%sum_all(red)
         fac = kmax(1)*2.0_dp*kappa*set%eta_f*sqrt(red(1)/red(2))
         if (precision == FOLD_FFT_DOUBLE) then
            bound = 2.0_dp*(14.0_dp*log(real(product(n), dp))/log(2.0_dp) + 30.0_dp)*epsilon(1.0_dp)/2.0_dp*fac
         else
            bound = 2.0_dp*(14.0_dp*log(real(product(n), dp))/log(2.0_dp) + 30.0_dp)*FOLD_SINGLE_ROUNDOFF*fac
         end if
         if (rank == 0) print '(a,es10.3,a,es10.3,a,es10.3)', "  |A_stencil u - A_spectral u| / |A u| = ", err, &
            ", bound ", bound, ", F ", fac
         call check(err <= bound, "stencil operator = spectral operator", failures)
      class default
         call check(.false., "factory did not give the FFT solver", failures)
      end select
      call s%destroy()
   end subroutine compare

   !> sum over the local half spectrum of wx |v|^2 (Hermitian weight of each x wavenumber)
   function weighted(wx, v) result(t)
      real(dp), intent(in) :: wx(:)
      complex(dp), intent(in) :: v(:, :, :, :)
      real(dp) :: t
      integer :: i
      t = 0.0_dp
      do i = 1, size(v, 1)
         t = t + wx(i)*sum(abs(v(i, :, :, :))**2)
      end do
   end function weighted

end program test_stokes_stencil
