!> Thin, checked helpers over the HDF5 Fortran API for pyfold run files.
!>
!> Every routine returns `stat` (FOLD_OK, FOLD_INPUT_ERROR for content that is
!> missing or wrong, FOLD_IO_ERROR for a file or HDF5 call that fails)
!> and an `errmsg` that names the object (full path, e.g. `/setup/resolved/dt`).
!>
!> Every HDF5 call's status is checked, also of the close calls: with HDF5's caches
!> (chunk cache, sieve buffer, metadata cache) a write can succeed in memory and its
!> data reach the disk only at h5dclose_f / h5fflush_f, so on a full disk it is often
!> a close or a flush that fails. A routine reports the *first* failure of its calls
!> (later clean-up calls never overwrite it), and the message ends with the system's
!> cause taken from the HDF5 error stack when there is one (e.g. "(No space left on
!> device)", "(File too large)"; see h5_cause).
!>
!> Array order: HDF5's Fortran API reverses the C dimension order, so a Fortran
!> array `a(d, n, nt)` is seen by h5py/xarray as `(nt, n, d)`. All shapes passed
!> here are in Fortran order; the *last* Fortran dimension is the one that can
!> grow (time, snapshot), which is the first one in Python.
!>
!> Checksums: every dataset create_extendible makes (all results and dimension scales)
!> is chunked with HDF5's Fletcher32 filter, so a damaged chunk fails its read (h5py,
!> h5dread_f) instead of returning flipped values; h5_verify reads a dataset whole.
!>
!> netCDF compatibility: coordinate datasets are HDF5 dimension scales
!> (H5DS, HDF5 high-level library) and every result variable has a scale attached
!> to each of its dimensions, which is what netCDF-4 and `h5netcdf` read as
!> named dimensions (`xarray.open_dataset(path, engine="h5netcdf")`).
module fold_h5
   use, intrinsic :: iso_c_binding, only: c_ptr, c_loc, c_char, c_null_char, c_int64_t, c_int, c_size_t, &
                                          c_funptr, c_funloc, c_null_ptr, c_associated, c_f_pointer
   use hdf5
   use h5ds, only: h5dsset_scale_f, h5dsattach_scale_f
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_IO_ERROR
   implicit none
   private

   public :: hid_t, hsize_t
   public :: h5_start, h5_stop, h5_open_file, h5_close_file, h5_flush
   public :: h5_exists, h5_shape
   public :: h5_read_int, h5_read_real, h5_read_int_array, h5_read_real_array
   public :: h5_attr_string, h5_attr_int, h5_attr_real, h5_read_attr_int
   public :: h5_make_group, h5_delete
   public :: h5_scale_int, h5_scale_real, h5_var_create, h5_var_append_real, h5_var_append_int
   public :: h5_var_length, h5_var_truncate, h5_verify
   public :: h5_put_real_array, h5_put_real_scalar, h5_put_int_scalar
   public :: h5_cause, h5_abandon_file, h5_wedged

   !> One entry of the HDF5 error stack (H5E_error2_t of H5Epublic.h).
   type, bind(C) :: h5e_entry_t
      integer(c_int64_t) :: cls_id, maj_num, min_num
      integer(c_int) :: line
      type(c_ptr) :: func_name, file_name, desc
   end type h5e_entry_t

   !> struct rlimit of Linux (rlim_t = unsigned long)
   type, bind(C) :: rlimit_t
      integer(c_int64_t) :: cur, max
   end type rlimit_t
   !> RLIMIT_FSIZE of Linux
   integer(c_int), parameter :: RLIMIT_FSIZE = 1_c_int

   interface
      !> herr_t H5Ewalk2(hid_t err_stack, H5E_direction_t direction, H5E_walk2_t func, void *client_data)
      integer(c_int) function c_h5ewalk2(stack, direction, func, data) bind(C, name="H5Ewalk2")
         import :: c_int, c_int64_t, c_funptr, c_ptr
         integer(c_int64_t), value :: stack
         integer(c_int), value :: direction
         type(c_funptr), value :: func
         type(c_ptr), value :: data
      end function c_h5ewalk2
      integer(c_size_t) function c_strlen(text) bind(C, name="strlen")
         import :: c_size_t, c_ptr
         type(c_ptr), value :: text
      end function c_strlen
      !> herr_t H5Fget_vfd_handle(hid_t file_id, hid_t fapl, void **file_handle)
      integer(c_int) function c_h5fget_vfd_handle(file, fapl, handle) bind(C, name="H5Fget_vfd_handle")
         import :: c_int, c_int64_t, c_ptr
         integer(c_int64_t), value :: file, fapl
         type(c_ptr), intent(out) :: handle
      end function c_h5fget_vfd_handle
      !> int memfd_create(const char *name, unsigned int flags) (Linux, glibc >= 2.27)
      integer(c_int) function c_memfd_create(name, flags) bind(C, name="memfd_create")
         import :: c_int, c_char
         character(kind=c_char), intent(in) :: name(*)
         integer(c_int), value :: flags
      end function c_memfd_create
      integer(c_int) function c_dup2(old, new) bind(C, name="dup2")
         import :: c_int
         integer(c_int), value :: old, new
      end function c_dup2
      integer(c_int) function c_close(fd) bind(C, name="close")
         import :: c_int
         integer(c_int), value :: fd
      end function c_close
      integer(c_int) function c_getrlimit(resource, limit) bind(C, name="getrlimit")
         import :: c_int, rlimit_t
         integer(c_int), value :: resource
         type(rlimit_t), intent(out) :: limit
      end function c_getrlimit
      integer(c_int) function c_setrlimit(resource, limit) bind(C, name="setrlimit")
         import :: c_int, rlimit_t
         integer(c_int), value :: resource
         type(rlimit_t), intent(in) :: limit
      end function c_setrlimit
   end interface

   !> Cause found by the current walk of the error stack (see h5_cause)
   character(len=200), save :: walk_cause = ""
   !> A file could not be closed (h5_abandon_file failed): terminating the HDF5
   !> library would crash on it, so h5_stop leaves it alone (see h5_wedged)
   logical, save :: wedged = .false.


   !> Element types of h5_var_create
   integer, parameter, public :: FOLD_H5_REAL = 1, FOLD_H5_INT = 2

contains

   ! ------------------------------------------------------------------ library

   !> Open the HDF5 library and silence its own error stack printing (errors are
   !> reported through stat/errmsg instead).
   subroutine h5_start(stat, errmsg)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      call h5open_f(err)
      if (.not. ok(err, "h5open_f: cannot initialise the HDF5 library", stat, errmsg)) return
      call h5eset_auto_f(0, err)
      call check_err(err, "h5eset_auto_f: cannot silence the HDF5 error printing", stat, errmsg)
   end subroutine h5_start

   !> Close the HDF5 library (not when a file could not be closed: see h5_wedged).
   subroutine h5_stop()
      integer :: err
      if (wedged) return
      call h5close_f(err)
   end subroutine h5_stop

   !> True when a file could not be closed even by h5_abandon_file: HDF5 1.10 keeps
   !> a freed file under its identifier, and terminating the library (h5close_f,
   !> MPI_Finalize, exit handlers) would crash on it. The program must then end
   !> without terminating the library (fold_run: _exit after its messages).
   logical function h5_wedged()
      h5_wedged = wedged
   end function h5_wedged

   !> Open an existing file read-only (`writable = .false.`) or read-write.
   subroutine h5_open_file(path, writable, file, stat, errmsg)
      !> File path
      character(len=*), intent(in) :: path
      !> Open for writing as well
      logical, intent(in) :: writable
      !> File identifier
      integer(hid_t), intent(out) :: file
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      logical :: there

      file = -1
      inquire (file=path, exist=there)
      if (.not. there) then
         stat = FOLD_IO_ERROR
         errmsg = "run file not found: "//trim(path)
         return
      end if
      if (writable) then
         call h5fopen_f(path, H5F_ACC_RDWR_F, file, err)
      else
         call h5fopen_f(path, H5F_ACC_RDONLY_F, file, err)
      end if
      if (.not. ok(err, "cannot open "//trim(path)//" as an HDF5 file", stat, errmsg)) return
   end subroutine h5_open_file

   !> Close a file (flushes it).
   subroutine h5_close_file(file, stat, errmsg)
      integer(hid_t), intent(inout) :: file
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      stat = FOLD_OK
      errmsg = ""
      if (file < 0) return
      call h5fclose_f(file, err)
      file = -1
      if (.not. ok(err, "closing the file failed (h5fclose_f: its last changes may not be on disk)", &
                   stat, errmsg)) wedged = .true.
   end subroutine h5_close_file

   !> Close a file whose writes fail (full disk) without writing anything more into it:
   !> the file on disk stays as the last successful write left it, as after a kill.
   !>
   !> HDF5's close flushes its caches; when that flush fails, HDF5 1.10 (before
   !> 1.14.1, HDFGroup/hdf5#2291) frees the file but keeps its identifier, and the
   !> library's termination (h5close_f, MPI_Finalize) then crashes on it (SIGSEGV).
   !> So the file driver's descriptor is first redirected (dup2) to an anonymous
   !> in-memory file (memfd_create): the close flushes into that and succeeds. Only
   !> for the sec2 driver (the default, one process writing). stat reports when the
   !> redirection or the close failed; then the library is wedged (h5_wedged). A
   !> file-size limit (ulimit -f) applies to the memory file too: its soft limit is
   !> raised to the hard limit for the close, and restored after it.
   subroutine h5_abandon_file(file, stat, errmsg)
      integer(hid_t), intent(inout) :: file
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      type(c_ptr) :: handle
      integer(c_int), pointer :: fd
      integer(c_int) :: mem, rc
      integer :: err
      type(rlimit_t) :: limit, raised
      logical :: have_limit

      stat = FOLD_OK
      errmsg = ""
      if (file < 0) return
      rc = c_h5fget_vfd_handle(int(file, c_int64_t), 0_c_int64_t, handle)
      if (rc < 0 .or. .not. c_associated(handle)) then
         stat = FOLD_IO_ERROR
         errmsg = "cannot abandon the file: H5Fget_vfd_handle failed"//h5_cause()
         wedged = .true.
         return
      end if
      call c_f_pointer(handle, fd)
      mem = c_memfd_create("fold_run_abandoned"//c_null_char, 0_c_int)
      if (mem < 0) then
         stat = FOLD_IO_ERROR
         errmsg = "cannot abandon the file: memfd_create failed"
         wedged = .true.
         return
      end if
      rc = c_dup2(mem, fd)
      if (c_close(mem) < 0) continue  ! fd keeps the memory file open
      if (rc < 0) then
         stat = FOLD_IO_ERROR
         errmsg = "cannot abandon the file: dup2 failed"
         wedged = .true.
         return
      end if
      have_limit = c_getrlimit(RLIMIT_FSIZE, limit) == 0
      if (have_limit) then
         raised = limit
         raised%cur = limit%max
         if (c_setrlimit(RLIMIT_FSIZE, raised) /= 0) have_limit = .false.
      end if
      call h5fclose_f(file, err)
      file = -1
      if (have_limit) then
         if (c_setrlimit(RLIMIT_FSIZE, limit) /= 0) continue
      end if
      call check_err(err, "closing the abandoned file failed (h5fclose_f)", stat, errmsg)
      if (stat /= FOLD_OK) wedged = .true.
   end subroutine h5_abandon_file

   !> Push everything written so far to disk (a crash then keeps it).
   subroutine h5_flush(file, stat, errmsg)
      integer(hid_t), intent(in) :: file
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      call h5fflush_f(file, H5F_SCOPE_GLOBAL_F, err)
      if (.not. ok(err, "flushing the file failed (h5fflush_f)", stat, errmsg)) return
   end subroutine h5_flush

   ! ------------------------------------------------------------------ queries

   !> True when every component of the path `name` (e.g. "/setup/resolved/dt") exists.
   function h5_exists(loc, name) result(there)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      logical :: there
      integer :: err, pos
      ! h5lexists_f fails (rather than returning false) when a parent group is
      ! missing, so each prefix is checked in turn.
      there = .false.
      do pos = 2, len(name)
         if (name(pos:pos) /= "/") cycle
         call h5lexists_f(loc, name(1:pos - 1), there, err)
         if (err < 0 .or. .not. there) then
            there = .false.
            return
         end if
      end do
      call h5lexists_f(loc, name, there, err)
      if (err < 0) there = .false.
   end function h5_exists

   !> Rank and Fortran-order shape of a dataset (rank 0 for a scalar dataspace).
   subroutine h5_shape(loc, name, rank, shape, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer, intent(out) :: rank
      !> Fortran-order extents (first `rank` entries used)
      integer(hsize_t), intent(out) :: shape(7)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: dset, space
      integer(hsize_t) :: maxdims(7)
      integer :: err

      rank = 0
      shape = 0
      if (.not. open_dataset(loc, name, dset, stat, errmsg)) return
      call h5dget_space_f(dset, space, err)
      if (ok(err, name//": cannot read its dataspace", stat, errmsg)) then
         call h5sget_simple_extent_ndims_f(space, rank, err)
         if (rank > 7) then
            stat = FOLD_INPUT_ERROR
            write (errmsg, '(a,a,i0)') name, ": rank > 7 not supported, got ", rank
         else if (rank > 0) then
            call h5sget_simple_extent_dims_f(space, shape(1:rank), maxdims(1:rank), err)
            if (err < 0) call check_err(err, name//": cannot read its extents", stat, errmsg)
         else if (rank < 0) then
            call check_err(rank, name//": cannot read its rank", stat, errmsg)
            rank = 0
         end if
         call h5sclose_f(space, err)
         call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
      end if
      call h5dclose_f(dset, err)
      call keep_first(err, name//": h5dclose_f failed", stat, errmsg)
   end subroutine h5_shape

   ! ------------------------------------------------------------------ reading

   !> Read an integer scalar dataset (rank 0, or one element). Its stored type
   !> must be an integer type.
   subroutine h5_read_int(loc, name, val, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(i8), intent(out), target :: val
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(i8), allocatable :: buf(:)
      val = 0
      call h5_read_int_array(loc, name, [integer(hsize_t) ::], buf, stat, errmsg)
      if (stat /= FOLD_OK) return
      val = buf(1)
   end subroutine h5_read_int

   !> Read a real scalar dataset (rank 0, or one element; integer storage is converted).
   subroutine h5_read_real(loc, name, val, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      real(dp), intent(out) :: val
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp), allocatable :: buf(:)
      val = 0.0_dp
      call h5_read_real_array(loc, name, [integer(hsize_t) ::], buf, stat, errmsg)
      if (stat /= FOLD_OK) return
      val = buf(1)
   end subroutine h5_read_real

   !> Read an integer dataset of the expected Fortran-order shape into a flat buffer.
   !> An empty `expected` means "a scalar": rank 0 or a single element.
   subroutine h5_read_int_array(loc, name, expected, buf, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: expected(:)
      integer(i8), allocatable, intent(out), target :: buf(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      allocate (buf(max(1_hsize_t, product(expected))))
      buf = 0
      call read_dataset(loc, name, expected, .false., h5kind_to_type(c_int64_t, H5_INTEGER_KIND), c_loc(buf), &
                        stat, errmsg)
   end subroutine h5_read_int_array

   !> Read a real (or integer, converted) dataset of the expected Fortran-order shape.
   subroutine h5_read_real_array(loc, name, expected, buf, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: expected(:)
      real(dp), allocatable, intent(out), target :: buf(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      allocate (buf(max(1_hsize_t, product(expected))))
      buf = 0.0_dp
      call read_dataset(loc, name, expected, .true., H5T_NATIVE_DOUBLE, c_loc(buf), stat, errmsg)
   end subroutine h5_read_real_array

   ! ------------------------------------------------------------------ attributes

   !> Write (replace) a variable-length UTF-8 string attribute (h5py reads it as `str`).
   subroutine h5_attr_string(loc, name, value, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name, value
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      character(kind=c_char, len=:), allocatable, target :: text
      type(c_ptr), target :: ptr(1)
      integer(hid_t) :: vtype
      integer :: err

      text = value//c_null_char
      ptr(1) = c_loc(text)
      call h5tcopy_f(H5T_C_S1, vtype, err)
      if (.not. ok(err, "attribute "//name//": h5tcopy_f failed", stat, errmsg)) return
      ! H5T_VARIABLE is (size_t)-1 in C; the 1.10 Fortran API has no named constant.
      call h5tset_size_f(vtype, -1_size_t, err)
      if (ok(err, "attribute "//name//": h5tset_size_f failed", stat, errmsg)) then
         call h5tset_cset_f(vtype, H5T_CSET_UTF8_F, err)
         call check_err(err, "attribute "//name//": h5tset_cset_f failed", stat, errmsg)
      end if
      if (stat == FOLD_OK) call scalar_attr(loc, name, vtype, c_loc(ptr), stat, errmsg)
      call h5tclose_f(vtype, err)
      call keep_first(err, "attribute "//name//": h5tclose_f failed", stat, errmsg)
   end subroutine h5_attr_string

   !> Write a 64-bit integer scalar attribute. An existing attribute's value is
   !> overwritten in place, not deleted and re-created (the counters `records_complete`,
   !> `steps_done` are updated this way: a kill never leaves the attribute missing).
   subroutine h5_attr_int(loc, name, value, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: value
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(i8), target :: v
      integer(hid_t) :: attr, itype
      integer :: err
      logical :: there
      v = value
      itype = h5kind_to_type(c_int64_t, H5_INTEGER_KIND)
      call h5aexists_f(loc, name, there, err)
      if (.not. ok(err, "attribute "//name//": cannot query", stat, errmsg)) return
      if (there) then
         call h5aopen_f(loc, name, attr, err)
         if (.not. ok(err, "attribute "//name//": cannot open", stat, errmsg)) return
         call write_attr(attr, name, itype, c_loc(v), stat, errmsg)
         return
      end if
      call scalar_attr(loc, name, itype, c_loc(v), stat, errmsg)
   end subroutine h5_attr_int

   !> Write (replace) a real scalar attribute.
   subroutine h5_attr_real(loc, name, value, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: value
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp), target :: v
      v = value
      call scalar_attr(loc, name, H5T_NATIVE_DOUBLE, c_loc(v), stat, errmsg)
   end subroutine h5_attr_real

   !> Read a scalar integer attribute; `found` = .false. (and stat = FOLD_OK) when absent.
   subroutine h5_read_attr_int(loc, name, value, found, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(i8), intent(out), target :: value
      logical, intent(out) :: found
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: attr
      integer :: err
      type(c_ptr) :: ptr
      value = 0
      stat = FOLD_OK
      errmsg = ""
      call h5aexists_f(loc, name, found, err)
      if (.not. ok(err, "attribute "//name//": cannot query", stat, errmsg)) return
      if (.not. found) return
      call h5aopen_f(loc, name, attr, err)
      if (.not. ok(err, "attribute "//name//": cannot open", stat, errmsg)) return
      ptr = c_loc(value)
      call h5aread_f(attr, h5kind_to_type(c_int64_t, H5_INTEGER_KIND), ptr, err)
      call check_err(err, "attribute "//name//": read failed", stat, errmsg)
      call h5aclose_f(attr, err)
      call keep_first(err, "attribute "//name//": h5aclose_f failed", stat, errmsg)
   end subroutine h5_read_attr_int

   ! ------------------------------------------------------------------ groups, links

   !> Create a group if it does not exist yet.
   subroutine h5_make_group(loc, name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: grp
      integer :: err
      stat = FOLD_OK
      errmsg = ""
      if (h5_exists(loc, name)) return
      call h5gcreate_f(loc, name, grp, err)
      if (.not. ok(err, name//": cannot create group", stat, errmsg)) return
      call h5gclose_f(grp, err)
      call keep_first(err, name//": h5gclose_f failed", stat, errmsg)
   end subroutine h5_make_group

   !> Unlink an object if it exists (used to replace a checkpoint).
   subroutine h5_delete(loc, name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      stat = FOLD_OK
      errmsg = ""
      if (.not. h5_exists(loc, name)) return
      call h5ldelete_f(loc, name, err)
      if (.not. ok(err, name//": cannot delete", stat, errmsg)) return
   end subroutine h5_delete

   ! ------------------------------------------------------------------ plain datasets

   !> Write a fixed-shape real dataset with units. A dataset that exists with the same
   !> shape and a floating-point type is overwritten in place: raw data only, no change
   !> to the file's metadata (group heaps, object headers), which a kill could leave
   !> torn. Any other previous object of that name is replaced.
   subroutine h5_put_real_array(loc, name, buf, shape, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      real(dp), intent(in), target, contiguous :: buf(:)
      !> Fortran-order shape; product(shape) == size(buf)
      integer(hsize_t), intent(in) :: shape(:)
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call put_dataset(loc, name, .false., shape, H5T_FLOAT_F, H5T_NATIVE_DOUBLE, c_loc(buf), units, long_name, &
                       stat, errmsg)
   end subroutine h5_put_real_array

   !> Write a scalar real dataset, in place when it exists (see h5_put_real_array).
   subroutine h5_put_real_scalar(loc, name, value, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: value
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      real(dp), target :: v(1)
      v(1) = value
      call put_dataset(loc, name, .true., [integer(hsize_t) ::], H5T_FLOAT_F, H5T_NATIVE_DOUBLE, c_loc(v), units, &
                       long_name, stat, errmsg)
   end subroutine h5_put_real_scalar

   !> Write a scalar 64-bit integer dataset (units "1"), in place when it exists (see
   !> h5_put_real_array).
   subroutine h5_put_int_scalar(loc, name, value, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(i8), intent(in) :: value
      character(len=*), intent(in) :: long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(i8), target :: v(1)
      v(1) = value
      call put_dataset(loc, name, .true., [integer(hsize_t) ::], H5T_INTEGER_F, &
                       h5kind_to_type(c_int64_t, H5_INTEGER_KIND), c_loc(v), "1", long_name, stat, errmsg)
   end subroutine h5_put_int_scalar

   ! ------------------------------------------------------------------ netCDF-style variables

   !> Create a 1-D integer coordinate that is also an HDF5 dimension scale named `name`.
   !> With `unlimited`, it starts empty and grows by h5_var_append_int.
   subroutine h5_scale_int(loc, name, values, unlimited, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(i8), intent(in), target, contiguous :: values(:)
      logical, intent(in) :: unlimited
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call write_scale(loc, name, FOLD_H5_INT, int(size(values), hsize_t), unlimited, &
                       h5kind_to_type(c_int64_t, H5_INTEGER_KIND), c_loc(values), units, long_name, stat, errmsg)
   end subroutine h5_scale_int

   !> Create a 1-D real coordinate that is also a dimension scale (see h5_scale_int).
   subroutine h5_scale_real(loc, name, values, unlimited, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      real(dp), intent(in), target, contiguous :: values(:)
      logical, intent(in) :: unlimited
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call write_scale(loc, name, FOLD_H5_REAL, int(size(values), hsize_t), unlimited, H5T_NATIVE_DOUBLE, &
                       c_loc(values), units, long_name, stat, errmsg)
   end subroutine h5_scale_real

   !> Create a variable over named dimensions, given in Fortran order (the last one
   !> may be unlimited and then starts at length 0). Each dimension must already
   !> exist as a scale of that name at `loc` and is attached to the variable.
   subroutine h5_var_create(loc, name, kind, dimnames, extents, unlimited, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      !> FOLD_H5_REAL or FOLD_H5_INT
      integer, intent(in) :: kind
      !> Dimension names, Fortran order (fastest first)
      character(len=*), intent(in) :: dimnames(:)
      !> Extents, Fortran order (the last is ignored when unlimited)
      integer(hsize_t), intent(in) :: extents(:)
      !> The last dimension grows (time, snapshot)
      logical, intent(in) :: unlimited
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: dset, scale
      integer :: err, k, r

      r = size(dimnames)
      call create_extendible(loc, name, kind, extents, unlimited, dset, stat, errmsg)
      if (stat /= FOLD_OK) return
      call annotate(dset, name, units, long_name, stat, errmsg)
      do k = 1, r
         if (stat /= FOLD_OK) exit
         call h5dopen_f(loc, trim(dimnames(k)), scale, err)
         if (.not. ok(err, name//": dimension scale "//trim(dimnames(k))//" missing", stat, errmsg)) exit
         ! The H5DS Fortran binding takes the C (row-major) dimension index + 1.
         call h5dsattach_scale_f(dset, scale, r - k + 1, err)
         call check_err(err, name//": cannot attach dimension "//trim(dimnames(k)), stat, errmsg)
         call close_dataset(scale, trim(dimnames(k)), stat, errmsg)
      end do
      call close_dataset(dset, name, stat, errmsg)
   end subroutine h5_var_create

   !> Current length of the last (growing) dimension of a variable.
   subroutine h5_var_length(loc, name, length, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(out) :: length
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: rank
      integer(hsize_t) :: shape(7)
      length = 0
      call h5_shape(loc, name, rank, shape, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (rank > 0) length = shape(rank)
   end subroutine h5_var_length

   !> Read a whole numeric dataset, so that HDF5 checks the Fletcher32 checksum of every
   !> chunk: a chunk that fails it (or data that cannot be read) gives FOLD_INPUT_ERROR
   !> and a message "name: damaged: ..." naming the dataset. Read in blocks of whole
   !> entries of the last (growing) dimension, at most ~64 MB each.
   subroutine h5_verify(loc, name, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hsize_t), parameter :: BLOCK_VALUES = 8388608_hsize_t
      integer :: rank, err
      integer(hsize_t) :: shape(7), offset(7), count(7), per_entry, rows, first
      integer(hid_t) :: dset, fspace, mspace
      real(dp), allocatable, target :: buf(:)
      type(c_ptr) :: ptr

      call h5_shape(loc, name, rank, shape, stat, errmsg)
      if (stat /= FOLD_OK) goto 9
      if (rank == 0) then
         call h5_read_real_array(loc, name, [integer(hsize_t) ::], buf, stat, errmsg)
         goto 9
      end if
      if (product(shape(1:rank)) == 0) return
      per_entry = max(1_hsize_t, product(shape(1:rank - 1)))
      rows = max(1_hsize_t, min(shape(rank), BLOCK_VALUES/per_entry))
      allocate (buf(per_entry*rows))
      if (.not. open_dataset(loc, name, dset, stat, errmsg)) goto 9
      call h5dget_space_f(dset, fspace, err)
      if (ok(err, name//": cannot read its dataspace", stat, errmsg)) then
         first = 0
         do while (first < shape(rank) .and. stat == FOLD_OK)
            offset = 0
            offset(rank) = first
            count(1:rank) = shape(1:rank)
            count(rank) = min(rows, shape(rank) - first)
            call h5sselect_hyperslab_f(fspace, H5S_SELECT_SET_F, offset(1:rank), count(1:rank), err)
            if (.not. ok(err, name//": cannot select a block", stat, errmsg)) exit
            call h5screate_simple_f(1, [per_entry*count(rank)], mspace, err)
            if (.not. ok(err, name//": cannot create the memory dataspace", stat, errmsg)) exit
            ptr = c_loc(buf)
            call h5dread_f(dset, H5T_NATIVE_DOUBLE, ptr, err, mspace, fspace)
            call check_err(err, name//": read failed", stat, errmsg)
            call h5sclose_f(mspace, err)
            call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
            first = first + count(rank)
         end do
         call h5sclose_f(fspace, err)
         call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
      end if
      call close_dataset(dset, name, stat, errmsg)
9     if (stat /= FOLD_OK) then
         stat = FOLD_INPUT_ERROR
         errmsg = name//": damaged (its data fails its checksum or cannot be read): "//trim(errmsg)
      end if
   end subroutine h5_verify

   !> Shrink (or grow) the last dimension of a variable to `length` records.
   subroutine h5_var_truncate(loc, name, length, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: length
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: dset
      integer :: rank, err
      integer(hsize_t) :: shape(7)
      call h5_shape(loc, name, rank, shape, stat, errmsg)
      if (stat /= FOLD_OK) return
      shape(rank) = length
      if (.not. open_dataset(loc, name, dset, stat, errmsg)) return
      call h5dset_extent_f(dset, shape(1:rank), err)
      call check_err(err, name//": cannot change its extent", stat, errmsg)
      call close_dataset(dset, name, stat, errmsg)
   end subroutine h5_var_truncate

   !> Write one record (all but the last dimension) at position `record` (1-based)
   !> of the growing dimension, extending it when needed.
   subroutine h5_var_append_real(loc, name, record, buf, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: record
      real(dp), intent(in), target, contiguous :: buf(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call write_record(loc, name, record, H5T_NATIVE_DOUBLE, c_loc(buf), int(size(buf), hsize_t), stat, errmsg)
   end subroutine h5_var_append_real

   !> Integer counterpart of h5_var_append_real.
   subroutine h5_var_append_int(loc, name, record, buf, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: record
      integer(i8), intent(in), target, contiguous :: buf(:)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call write_record(loc, name, record, h5kind_to_type(c_int64_t, H5_INTEGER_KIND), c_loc(buf), &
                        int(size(buf), hsize_t), stat, errmsg)
   end subroutine h5_var_append_int

   ! ------------------------------------------------------------------ internals

   !> Turn an HDF5 error code into stat/errmsg; true when the call succeeded. The
   !> message is `what` followed by the system's cause (h5_cause), so call this right
   !> after the failing HDF5 call, before any other HDF5 call clears the error stack.
   logical function ok(err, what, stat, errmsg)
      integer, intent(in) :: err
      character(len=*), intent(in) :: what
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      ok = err >= 0
      if (ok) then
         stat = FOLD_OK
         errmsg = ""
      else
         stat = FOLD_IO_ERROR
         errmsg = what//h5_cause()
      end if
   end function ok

   !> Record a failed call unless an earlier call of the same routine failed already
   !> (clean-up calls after a failure never replace its message).
   subroutine keep_first(err, what, stat, errmsg)
      integer, intent(in) :: err
      character(len=*), intent(in) :: what
      integer, intent(inout) :: stat
      character(len=msg_len), intent(inout) :: errmsg
      if (err >= 0 .or. stat /= FOLD_OK) return
      stat = FOLD_IO_ERROR
      errmsg = what//h5_cause()
   end subroutine keep_first

   !> Close a dataset, reporting a failure (the data held in HDF5's chunk cache or
   !> sieve buffer is written at this point) unless an earlier failure is reported.
   subroutine close_dataset(dset, name, stat, errmsg)
      integer(hid_t), intent(in) :: dset
      character(len=*), intent(in) :: name
      integer, intent(inout) :: stat
      character(len=msg_len), intent(inout) :: errmsg
      integer :: err
      if (dset < 0) return
      call h5dclose_f(dset, err)
      call keep_first(err, name//": closing the dataset failed (h5dclose_f: its data did not reach the file)", &
                      stat, errmsg)
   end subroutine close_dataset

   !> The system's cause of the last failed HDF5 call, from the library's error stack:
   !> " (No space left on device)" for a write the file system refused (the text of
   !> errno that HDF5's file driver records), else the innermost HDF5 message, e.g.
   !> " (HDF5: ...)"; "" when the stack is empty.
   function h5_cause() result(cause)
      character(len=:), allocatable :: cause
      integer(c_int) :: rc
      walk_cause = ""
      ! H5E_DEFAULT = 0, H5E_WALK_UPWARD = 0 (innermost entry first)
      rc = c_h5ewalk2(0_c_int64_t, 0_c_int, c_funloc(walk_entry), c_null_ptr)
      if (rc < 0 .or. len_trim(walk_cause) == 0) then
         cause = ""
      else
         cause = " ("//trim(walk_cause)//")"
      end if
   end function h5_cause

   !> H5Ewalk2 callback: keep the first errno text ("error message = '...'") of the
   !> stack, else its innermost description.
   integer(c_int) function walk_entry(n, entry, data) bind(C)
      integer(c_int), value :: n
      type(h5e_entry_t), intent(in) :: entry
      type(c_ptr), value :: data
      character(kind=c_char), pointer :: chars(:)
      character(len=:), allocatable :: text
      integer :: k, lo, hi
      integer(c_size_t) :: length
      character(len=*), parameter :: KEY = "error message = '"

      walk_entry = 0
      if (c_associated(data)) continue  ! (no client data)
      if (.not. c_associated(entry%desc)) return
      length = c_strlen(entry%desc)
      call c_f_pointer(entry%desc, chars, [length])
      allocate (character(len=length) :: text)
      do k = 1, int(length)
         text(k:k) = chars(k)
      end do
      lo = index(text, KEY)
      if (lo > 0) then
         hi = index(text(lo + len(KEY):), "'")
         if (hi > 1) then
            walk_cause = text(lo + len(KEY):lo + len(KEY) + hi - 2)
            walk_entry = 1  ! stop the walk: this is the system's cause
            return
         end if
      end if
      if (n == 0 .and. len_trim(walk_cause) == 0) walk_cause = "HDF5: "//text
   end function walk_entry

   !> Like ok() for calls whose failure is the last thing a routine reports.
   subroutine check_err(err, what, stat, errmsg)
      integer, intent(in) :: err
      character(len=*), intent(in) :: what
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      if (ok(err, what, stat, errmsg)) return
   end subroutine check_err

   logical function open_dataset(loc, name, dset, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hid_t), intent(out) :: dset
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      dset = -1
      open_dataset = .false.
      if (.not. h5_exists(loc, name)) then
         ! A missing dataset is a defect of the file's content, not of the disk.
         stat = FOLD_INPUT_ERROR
         errmsg = name//": dataset missing"
         return
      end if
      call h5dopen_f(loc, name, dset, err)
      open_dataset = ok(err, name//": not a dataset", stat, errmsg)
   end function open_dataset

   !> Open a dataset and check its shape against `expected` (Fortran order; empty =
   !> scalar or one element); returns its type class.
   logical function checked_dataset(loc, name, expected, dset, tclass, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: expected(:)
      integer(hid_t), intent(out) :: dset
      integer, intent(out) :: tclass
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: rank, err, k
      integer(hsize_t) :: shape(7)
      integer(hid_t) :: ftype
      character(len=200) :: want, got

      checked_dataset = .false.
      tclass = -1
      dset = -1
      call h5_shape(loc, name, rank, shape, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (size(expected) == 0) then
         if (rank > 0) then
            if (product(shape(1:rank)) /= 1) then
               stat = FOLD_INPUT_ERROR
               write (errmsg, '(a,a,i0,a)') name, ": must be a scalar, got ", product(shape(1:rank)), " values"
               return
            end if
         end if
      else if (rank /= size(expected) .or. any(shape(1:rank) /= expected)) then
         ! Report shapes in the Python (C) order the file's writer sees.
         write (want, '(*(i0,:,", "))') (expected(k), k=size(expected), 1, -1)
         write (got, '(*(i0,:,", "))') (shape(k), k=rank, 1, -1)
         stat = FOLD_INPUT_ERROR
         errmsg = name//": expected shape ("//trim(want)//"), got ("//trim(got)//")"
         return
      end if
      if (.not. open_dataset(loc, name, dset, stat, errmsg)) return
      call h5dget_type_f(dset, ftype, err)
      if (ok(err, name//": cannot read its type", stat, errmsg)) then
         call h5tget_class_f(ftype, tclass, err)
         call check_err(err, name//": cannot read its type class", stat, errmsg)
         call h5tclose_f(ftype, err)
         call keep_first(err, name//": h5tclose_f failed", stat, errmsg)
      end if
      if (stat /= FOLD_OK) then
         call h5dclose_f(dset, err)
         dset = -1
         return
      end if
      checked_dataset = .true.
   end function checked_dataset

   !> Open `name` when it is a dataset of exactly this Fortran-order shape (empty: a
   !> scalar dataspace) and type class; false (nothing open) otherwise.
   logical function open_same(loc, name, shape, tclass, dset)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: shape(:)
      integer, intent(in) :: tclass
      integer(hid_t), intent(out) :: dset
      integer :: rank, stat, err, have
      integer(hsize_t) :: got(7)
      integer(hid_t) :: ftype
      character(len=msg_len) :: errmsg

      open_same = .false.
      dset = -1
      if (.not. h5_exists(loc, name)) return
      call h5_shape(loc, name, rank, got, stat, errmsg)
      if (stat /= FOLD_OK .or. rank /= size(shape)) return
      if (any(got(1:rank) /= shape)) return
      call h5dopen_f(loc, name, dset, err)
      if (err < 0) return
      have = -1
      call h5dget_type_f(dset, ftype, err)
      if (err >= 0) then
         call h5tget_class_f(ftype, have, err)
         if (err < 0) have = -1
         call h5tclose_f(ftype, err)
         if (err < 0) have = -1
      end if
      open_same = have == tclass
      if (.not. open_same) call h5dclose_f(dset, err)
   end function open_same

   !> Create an attribute, deleting a previous one of the same name.
   subroutine replace_attr(loc, name, atype, space, attr, stat, errmsg)
      integer(hid_t), intent(in) :: loc, atype, space
      character(len=*), intent(in) :: name
      integer(hid_t), intent(out) :: attr
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      logical :: there
      integer :: err
      attr = -1
      call h5aexists_f(loc, name, there, err)
      if (.not. ok(err, "attribute "//name//": cannot query", stat, errmsg)) return
      if (there) then
         call h5adelete_f(loc, name, err)
         if (.not. ok(err, "attribute "//name//": cannot delete the old value", stat, errmsg)) return
      end if
      call h5acreate_f(loc, name, atype, space, attr, err)
      if (.not. ok(err, "attribute "//name//": cannot create", stat, errmsg)) return
   end subroutine replace_attr

   !> units and long_name attributes of a variable.
   subroutine annotate(dset, name, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: dset
      character(len=*), intent(in) :: name, units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call h5_attr_string(dset, "units", units, stat, errmsg)
      if (stat == FOLD_OK) call h5_attr_string(dset, "long_name", long_name, stat, errmsg)
      if (stat /= FOLD_OK) errmsg = name//": "//trim(errmsg)
   end subroutine annotate

   !> Chunked dataset, checksummed by HDF5's Fletcher32 filter, whose last Fortran
   !> dimension may be unlimited.
   subroutine create_extendible(loc, name, kind, extents, unlimited, dset, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer, intent(in) :: kind
      integer(hsize_t), intent(in) :: extents(:)
      logical, intent(in) :: unlimited
      integer(hid_t), intent(out) :: dset
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: space, dcpl, dtype
      integer(hsize_t) :: dims(size(extents)), maxdims(size(extents)), chunk(size(extents))
      integer :: err, r
      integer(hsize_t), parameter :: target_chunk = 8192  ! elements per chunk, ~64 kB of doubles
      !> Records per chunk at most: a damaged chunk (its Fletcher32 checksum fails) loses
      !> no more than these records to a reader that keeps the intact part
      integer(hsize_t), parameter :: max_records = 64

      dset = -1
      r = size(extents)
      dims = extents
      maxdims = extents
      if (kind == FOLD_H5_REAL) then
         dtype = H5T_NATIVE_DOUBLE
      else
         dtype = h5kind_to_type(c_int64_t, H5_INTEGER_KIND)
      end if
      call h5pcreate_f(H5P_DATASET_CREATE_F, dcpl, err)
      if (.not. ok(err, name//": h5pcreate_f failed", stat, errmsg)) return
      ! Every dataset is chunked, so that HDF5's Fletcher32 filter checksums its data:
      ! a reader (h5py, this module) gets a read error instead of a flipped value.
      chunk = max(1_hsize_t, extents)
      if (unlimited) then
         dims(r) = 0
         maxdims(r) = H5S_UNLIMITED_F
         ! Whole records per chunk; several records when a record is small.
         chunk(r) = max(1_hsize_t, min(max_records, target_chunk/max(1_hsize_t, product(chunk(1:r - 1)))))
      end if
      call h5pset_chunk_f(dcpl, r, chunk, err)
      if (ok(err, name//": cannot set chunking", stat, errmsg)) then
         call h5pset_fletcher32_f(dcpl, err)
         call check_err(err, name//": cannot set the Fletcher32 checksum filter", stat, errmsg)
      end if
      if (stat /= FOLD_OK) then
         call h5pclose_f(dcpl, err)
         return
      end if
      call h5screate_simple_f(r, dims, space, err, maxdims)
      if (.not. ok(err, name//": cannot create dataspace", stat, errmsg)) then
         call h5pclose_f(dcpl, err)
         return
      end if
      call h5dcreate_f(loc, name, dtype, space, dset, err, dcpl)
      call check_err(err, name//": cannot create dataset (does it exist already?)", stat, errmsg)
      call h5sclose_f(space, err)
      call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
      call h5pclose_f(dcpl, err)
      call keep_first(err, name//": h5pclose_f failed", stat, errmsg)
      if (stat /= FOLD_OK .and. dset >= 0) then
         call h5dclose_f(dset, err)
         dset = -1
      end if
   end subroutine create_extendible

   !> Read dataset `name` of the expected shape (checked_dataset) into ptr as mtype. Its
   !> stored type must be an integer type, or (numbers) an integer or floating-point type.
   subroutine read_dataset(loc, name, expected, numbers, mtype, ptr, stat, errmsg)
      integer(hid_t), intent(in) :: loc, mtype
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: expected(:)
      logical, intent(in) :: numbers
      type(c_ptr), intent(in) :: ptr
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: dset
      integer :: err, tclass
      type(c_ptr) :: dest  ! h5dread_f takes its buffer pointer intent(inout)

      if (.not. checked_dataset(loc, name, expected, dset, tclass, stat, errmsg)) return
      if (tclass /= H5T_INTEGER_F .and. .not. (numbers .and. tclass == H5T_FLOAT_F)) then
         stat = FOLD_INPUT_ERROR
         if (numbers) then
            errmsg = name//": must be stored as a number"
         else
            errmsg = name//": must be stored as an integer"
         end if
      else
         dest = ptr
         call h5dread_f(dset, mtype, dest, err)
         call check_err(err, name//": read failed", stat, errmsg)
      end if
      call h5dclose_f(dset, err)
      call keep_first(err, name//": h5dclose_f failed", stat, errmsg)
   end subroutine read_dataset

   !> Create (replace) a scalar attribute of type atype and write the value at ptr.
   subroutine scalar_attr(loc, name, atype, ptr, stat, errmsg)
      integer(hid_t), intent(in) :: loc, atype
      character(len=*), intent(in) :: name
      type(c_ptr), intent(in) :: ptr
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: space, attr
      integer :: err
      call h5screate_f(H5S_SCALAR_F, space, err)
      if (.not. ok(err, "attribute "//name//": h5screate_f failed", stat, errmsg)) return
      call replace_attr(loc, name, atype, space, attr, stat, errmsg)
      if (stat == FOLD_OK) call write_attr(attr, name, atype, ptr, stat, errmsg)
      call h5sclose_f(space, err)
      call keep_first(err, "attribute "//name//": h5sclose_f failed", stat, errmsg)
   end subroutine scalar_attr

   !> Write the value at ptr to the open attribute attr and close it.
   subroutine write_attr(attr, name, atype, ptr, stat, errmsg)
      integer(hid_t), intent(in) :: attr, atype
      character(len=*), intent(in) :: name
      type(c_ptr), intent(in) :: ptr
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      call h5awrite_f(attr, atype, ptr, err)
      call check_err(err, "attribute "//name//": write failed", stat, errmsg)
      call h5aclose_f(attr, err)
      call keep_first(err, "attribute "//name//": h5aclose_f failed", stat, errmsg)
   end subroutine write_attr

   !> Write a fixed-shape dataset of memory type mtype from ptr, with units and
   !> long_name: a scalar dataspace when `scalar`, else `shape`. When `name` exists with
   !> this shape and type class tclass (open_same) its raw data is overwritten in place;
   !> otherwise any previous object of that name is replaced by a new dataset.
   subroutine put_dataset(loc, name, scalar, shape, tclass, mtype, ptr, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc, mtype
      character(len=*), intent(in) :: name
      logical, intent(in) :: scalar
      integer(hsize_t), intent(in) :: shape(:)
      integer, intent(in) :: tclass
      type(c_ptr), intent(in) :: ptr
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: space, dset
      integer :: err
      stat = FOLD_OK
      errmsg = ""
      if (open_same(loc, name, shape, tclass, dset)) then
         call h5dwrite_f(dset, mtype, ptr, err)
         call check_err(err, name//": write failed", stat, errmsg)
         call close_dataset(dset, name, stat, errmsg)
         return
      end if
      call h5_delete(loc, name, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (scalar) then
         call h5screate_f(H5S_SCALAR_F, space, err)
      else
         call h5screate_simple_f(size(shape), shape, space, err)
      end if
      if (.not. ok(err, name//": dataspace", stat, errmsg)) return
      call h5dcreate_f(loc, name, mtype, space, dset, err)
      call check_err(err, name//": cannot create dataset", stat, errmsg)
      call h5sclose_f(space, err)
      call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
      if (stat /= FOLD_OK) return
      call h5dwrite_f(dset, mtype, ptr, err)
      if (ok(err, name//": write failed", stat, errmsg)) call annotate(dset, name, units, long_name, stat, errmsg)
      call close_dataset(dset, name, stat, errmsg)
   end subroutine put_dataset

   !> A 1-D coordinate of n values at ptr (memory type mtype) that is a dimension scale.
   subroutine write_scale(loc, name, kind, n, unlimited, mtype, ptr, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: loc, mtype
      character(len=*), intent(in) :: name
      integer, intent(in) :: kind
      integer(hsize_t), intent(in) :: n
      logical, intent(in) :: unlimited
      type(c_ptr), intent(in) :: ptr
      character(len=*), intent(in) :: units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(hid_t) :: dset
      integer :: err
      call create_extendible(loc, name, kind, [n], unlimited, dset, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (n > 0) then
         call h5dwrite_f(dset, mtype, ptr, err)
         if (.not. ok(err, name//": write failed", stat, errmsg)) then
            call close_dataset(dset, name, stat, errmsg)
            return
         end if
      end if
      call finish_scale(dset, name, units, long_name, stat, errmsg)
   end subroutine write_scale

   subroutine finish_scale(dset, name, units, long_name, stat, errmsg)
      integer(hid_t), intent(in) :: dset
      character(len=*), intent(in) :: name, units, long_name
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: err
      call h5dsset_scale_f(dset, err, name)
      if (ok(err, name//": cannot make it a dimension scale", stat, errmsg)) &
         call annotate(dset, name, units, long_name, stat, errmsg)
      call close_dataset(dset, name, stat, errmsg)
   end subroutine finish_scale

   !> Write entry `record` (1-based, along the last, growing dimension; extended when
   !> needed) of the variable `name` from ptr (count values of memory type mtype). A
   !> failure message names the dataset by its full path (variables are created at
   !> the root: "a2: ..." becomes "/a2: ...").
   subroutine write_record(loc, name, record, mtype, ptr, count, stat, errmsg)
      integer(hid_t), intent(in) :: loc
      character(len=*), intent(in) :: name
      integer(hsize_t), intent(in) :: record
      integer(hid_t), intent(in) :: mtype
      type(c_ptr), intent(in) :: ptr
      integer(hsize_t), intent(in) :: count
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      call write_one_record()
      if (stat /= FOLD_OK .and. name(1:1) /= "/") errmsg = "/"//trim(errmsg)

   contains

      !> The write itself, on write_record's arguments.
      subroutine write_one_record()
         integer(hid_t) :: dset, fspace, mspace
         integer(hsize_t) :: shape(7), offset(7), block(7)
         integer :: rank, err

         call h5_shape(loc, name, rank, shape, stat, errmsg)
         if (stat /= FOLD_OK) return
         if (product(shape(1:rank - 1)) /= count) then
            stat = FOLD_INPUT_ERROR
            write (errmsg, '(a,a,i0,a,i0)') name, ": record of ", count, " values, expected ", product(shape(1:rank - 1))
            return
         end if
         if (.not. open_dataset(loc, name, dset, stat, errmsg)) return
         if (record > shape(rank)) then
            shape(rank) = record
            call h5dset_extent_f(dset, shape(1:rank), err)
            if (.not. ok(err, name//": cannot extend", stat, errmsg)) then
               call close_dataset(dset, name, stat, errmsg)
               return
            end if
         end if
         call h5dget_space_f(dset, fspace, err)
         if (.not. ok(err, name//": cannot read its dataspace", stat, errmsg)) then
            call close_dataset(dset, name, stat, errmsg)
            return
         end if
         offset = 0
         offset(rank) = record - 1
         block(1:rank) = shape(1:rank)
         block(rank) = 1
         call h5sselect_hyperslab_f(fspace, H5S_SELECT_SET_F, offset(1:rank), block(1:rank), err)
         if (ok(err, name//": cannot select the record", stat, errmsg)) then
            call h5screate_simple_f(1, [count], mspace, err)
            if (ok(err, name//": cannot create the memory dataspace", stat, errmsg)) then
               call h5dwrite_f(dset, mtype, ptr, err, mspace, fspace)
               call check_err(err, name//": write failed", stat, errmsg)
               call h5sclose_f(mspace, err)
               call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
            end if
         end if
         call h5sclose_f(fspace, err)
         call keep_first(err, name//": h5sclose_f failed", stat, errmsg)
         ! The data may reach the file only here (chunk cache): a full disk fails the close.
         call close_dataset(dset, name, stat, errmsg)
      end subroutine write_one_record
   end subroutine write_record

end module fold_h5
