!> Stack smoke test: FFTW-MPI slab-decomposed 3-D r2c transform; the single mode
!> is found with amplitude N/2 on the rank that owns it, nothing elsewhere.
program smoke_fftw_mpi
   use, intrinsic :: iso_c_binding
   use mpi_f08
   implicit none
   include 'fftw3-mpi.f03'
   integer(c_intptr_t), parameter :: n1 = 12, n2 = 10, n3 = 8
   integer(c_intptr_t) :: alloc_local, local_n3, local_k0, i, j, k
   type(c_ptr) :: plan, cdata
   real(c_double), pointer :: f(:, :, :)
   complex(c_double_complex), pointer :: fh(:, :, :)
   real(c_double), parameter :: pi = acos(-1.0_c_double)
   real(c_double) :: err, gerr, peak, gpeak
   integer :: rank

   call MPI_Init()
   call fftw_mpi_init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   ! slabs along the slowest Fortran index (FFTW's first, row-major)
   alloc_local = fftw_mpi_local_size_3d(n3, n2, n1/2 + 1, MPI_COMM_WORLD%MPI_VAL, local_n3, local_k0)
   cdata = fftw_alloc_complex(alloc_local)
   call c_f_pointer(cdata, f, [2*(n1/2 + 1), n2, local_n3])
   call c_f_pointer(cdata, fh, [n1/2 + 1, n2, local_n3])
   plan = fftw_mpi_plan_dft_r2c_3d(n3, n2, n1, f, fh, MPI_COMM_WORLD%MPI_VAL, FFTW_ESTIMATE)
   f = 0
   do k = 1, local_n3
      do j = 1, n2
         do i = 1, n1
            f(i, j, k) = cos(2*pi*(2*(i - 1)/real(n1, c_double) + (k + local_k0 - 1)/real(n3, c_double)))
         end do
      end do
   end do
   call fftw_mpi_execute_dft_r2c(plan, f, fh)
   ! mode (2, 0, 1): bin (3, 1, global k = 2)
   peak = 0
   do k = 1, local_n3
      if (k + local_k0 == 2) then
         peak = real(fh(3, 1, k))
         fh(3, 1, k) = 0
      end if
   end do
   err = 0
   if (local_n3 > 0) err = maxval(abs(fh(:, :, 1:local_n3)))
   call MPI_Allreduce(err, gerr, 1, MPI_DOUBLE_PRECISION, MPI_MAX, MPI_COMM_WORLD)
   call MPI_Allreduce(peak, gpeak, 1, MPI_DOUBLE_PRECISION, MPI_SUM, MPI_COMM_WORLD)
   gerr = max(gerr/(n1*n2*n3), abs(gpeak - n1*n2*n3/2.0_c_double)/(n1*n2*n3))
   call fftw_destroy_plan(plan)
   call fftw_free(cdata)
   if (gerr > 1.0e-9_c_double) then
      if (rank == 0) print '(a,es10.3)', "smoke_fftw_mpi: error ", gerr
      call MPI_Abort(MPI_COMM_WORLD, 1)
   end if
   if (rank == 0) print '(a,es10.3)', "smoke_fftw_mpi: ok, max error ", gerr
   call fftw_mpi_cleanup()
   call MPI_Finalize()
end program smoke_fftw_mpi
