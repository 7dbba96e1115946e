!> Stack smoke test: mpi_f08 is usable and a reduction over all ranks is exact.
program smoke_mpi
   use mpi_f08
   implicit none
   integer :: rank, nranks, total, ierr
   call MPI_Init(ierr)
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   call MPI_Allreduce(rank, total, 1, MPI_INTEGER, MPI_SUM, MPI_COMM_WORLD)
   if (total /= nranks*(nranks - 1)/2) then
      print '(a,i0,a,i0)', "smoke_mpi: rank sum ", total, " /= expected for size ", nranks
      call MPI_Abort(MPI_COMM_WORLD, 1)
   end if
   if (rank == 0) print '(a,i0,a)', "smoke_mpi: ok on ", nranks, " ranks"
   call MPI_Finalize()
end program smoke_mpi
