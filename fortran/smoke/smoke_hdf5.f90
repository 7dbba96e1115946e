!> Stack smoke test: parallel HDF5 (MPI-IO). Every rank writes its own row of a
!> shared dataset collectively; rank 0 reads the file back and checks each row.
program smoke_hdf5
   use mpi_f08
   use hdf5
   implicit none
   integer, parameter :: ncol = 5
   character(len=*), parameter :: fname = "smoke_hdf5.h5"
   integer :: rank, nranks, err, j, k
   integer(hid_t) :: fapl, file, space, mspace, dset, xfer
   integer(hsize_t) :: dims(2), offs(2), cnt(2)
   double precision :: row(ncol, 1)
   double precision, allocatable :: all(:, :)

   call MPI_Init()
   call MPI_Comm_rank(MPI_COMM_WORLD, rank)
   call MPI_Comm_size(MPI_COMM_WORLD, nranks)
   call h5open_f(err)
   call h5pcreate_f(H5P_FILE_ACCESS_F, fapl, err)
   call h5pset_fapl_mpio_f(fapl, MPI_COMM_WORLD%MPI_VAL, MPI_INFO_NULL%MPI_VAL, err)
   call h5fcreate_f(fname, H5F_ACC_TRUNC_F, file, err, access_prp=fapl)
   dims = [integer(hsize_t) :: ncol, nranks]
   call h5screate_simple_f(2, dims, space, err)
   call h5dcreate_f(file, "rows", H5T_NATIVE_DOUBLE, space, dset, err)
   offs = [integer(hsize_t) :: 0, rank]
   cnt = [integer(hsize_t) :: ncol, 1]
   call h5sselect_hyperslab_f(space, H5S_SELECT_SET_F, offs, cnt, err)
   call h5screate_simple_f(2, cnt, mspace, err)
   call h5pcreate_f(H5P_DATASET_XFER_F, xfer, err)
   call h5pset_dxpl_mpio_f(xfer, H5FD_MPIO_COLLECTIVE_F, err)
   row(:, 1) = [(100.0d0*rank + j, j=1, ncol)]
   call h5dwrite_f(dset, H5T_NATIVE_DOUBLE, row, cnt, err, mem_space_id=mspace, file_space_id=space, xfer_prp=xfer)
   if (err /= 0) call fail("collective write failed")
   call h5dclose_f(dset, err)
   call h5sclose_f(mspace, err)
   call h5sclose_f(space, err)
   call h5pclose_f(xfer, err)
   call h5fclose_f(file, err)
   call h5pclose_f(fapl, err)
   call MPI_Barrier(MPI_COMM_WORLD)
   if (rank == 0) then
      allocate (all(ncol, nranks))
      call h5fopen_f(fname, H5F_ACC_RDONLY_F, file, err)
      call h5dopen_f(file, "rows", dset, err)
      call h5dread_f(dset, H5T_NATIVE_DOUBLE, all, dims, err)
      if (err /= 0) call fail("read back failed")
      do j = 0, nranks - 1
         if (maxval(abs(all(:, j + 1) - [(100.0d0*j + k, k=1, ncol)])) > 0) call fail("row content differs")
      end do
      call h5dclose_f(dset, err)
      call h5fclose_f(file, err)
      print '(a,i0,a)', "smoke_hdf5: ok, ", nranks, " ranks wrote one row each"
      open (newunit=j, file=fname)
      close (j, status="delete")
   end if
   call h5close_f(err)
   call MPI_Finalize()
contains
   subroutine fail(why)
      character(len=*), intent(in) :: why
      print '(2a)', "smoke_hdf5: ", why
      call MPI_Abort(MPI_COMM_WORLD, 1)
   end subroutine fail
end program smoke_hdf5
