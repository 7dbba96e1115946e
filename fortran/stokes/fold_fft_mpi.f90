!> FFTW-MPI slab transport: each rank owns a slab of the slowest Fortran index
!> (z in 3-D, y in 2-D) in real space. A distributed transform is local 1-D/2-D
!> FFTs plus global transposes (all-to-alls); FFTW-MPI's natural output needs two
!> (to distribute y for the z transform, and back), the transposed output only one.
!> In 3-D the spectrum is therefore left transposed by default: c(nxh, n3, local
!> n2), y distributed (FFTW_MPI_TRANSPOSED_OUT on r2c, FFTW_MPI_TRANSPOSED_IN on
!> c2r); the solver works mode by mode through the transport's spectral map
!> (fold_fft_transport). In 2-D the transposed output would distribute the x
!> wavenumbers and put them second, so the 2-D spectrum keeps the natural layout.
!> Executable only (needs MPI); the solver sees it as an fft_transport_t.
module fold_fft_mpi
   use, intrinsic :: iso_c_binding
   use mpi_f08, only: MPI_Comm, MPI_Comm_rank, MPI_Comm_size, MPI_Allreduce, MPI_IN_PLACE, &
                      MPI_DOUBLE_PRECISION, MPI_SUM, MPI_MAX, MPI_Sendrecv, MPI_STATUS_IGNORE
   use fold_kinds, only: dp, ip, i8, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_fft_transport, only: fft_transport_t, fft_field_t, field_free, plans_free, plan_flag, spectral_natural, &
                                 single_plans_check, grid_check
   implicit none
   private

   include 'fftw3-mpi.f03'

   !> FFTW-MPI in-place r2c/c2r plans of one slab-decomposed grid.
   type, extends(fft_transport_t), public :: fft_mpi_t
      type(MPI_Comm) :: comm
      !> The spectrum is left transposed (3-D default)
      logical :: transposed = .false.
   contains
      procedure :: transform => slab_transform
      procedure :: plan_single => slab_plan_single
      procedure :: sum_all => slab_sum
      procedure :: max_all => slab_max
      procedure :: z_halo => slab_z_halo
      procedure :: destroy => slab_destroy
   end type fft_mpi_t

   public :: fft_mpi_create, fft_mpi_start

contains

   !> Initialise FFTW-MPI, double and single precision (separate libraries): once per
   !> process after MPI_Init, before any plan (FFTW ignores repeated calls).
   subroutine fft_mpi_start()
      call fftw_mpi_init()
      call fftwf_mpi_init()
   end subroutine fft_mpi_start

   !> Make the distributed plans once (collective over comm). fftw_mpi_init must
   !> have been called after MPI_Init. transposed (3-D only, default true): leave
   !> the spectrum transposed (one all-to-all per transform instead of two).
   subroutine fft_mpi_create(self, comm, dim, n, effort, stat, errmsg, transposed)
      type(fft_mpi_t), intent(inout) :: self
      type(MPI_Comm), intent(in) :: comm
      integer(ip), intent(in) :: dim
      integer(ip), intent(in) :: n(3)
      integer, intent(in) :: effort
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      logical, intent(in), optional :: transposed
      integer(c_intptr_t) :: alloc, local_n, local_0, local_n1, local_1
      integer(c_int) :: flag_fwd, flag_bwd
      logical :: tr
      type(fft_field_t) :: scratch

      call grid_check("fft_mpi_create", dim, n, stat, errmsg)
      if (stat /= FOLD_OK) return
      tr = dim == 3
      if (present(transposed)) tr = transposed .and. dim == 3
      call slab_destroy(self)
      self%transposed = tr
      self%comm = comm
      call MPI_Comm_rank(comm, self%rank)
      call MPI_Comm_size(comm, self%nranks)
      self%dim = dim
      self%n = 1
      self%n(1:dim) = n(1:dim)
      self%nxh = self%n(1)/2 + 1
      self%nxp = 2*self%nxh
      self%nl = self%n
      self%off = 0
      flag_fwd = plan_flag(effort)
      flag_bwd = plan_flag(effort)
      if (dim == 3 .and. tr) then
         ! row-major (n3, n2, nxh) in, (n2, n3, nxh) out: Fortran c(nxh, n3, local n2)
         alloc = fftw_mpi_local_size_3d_transposed(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                                   int(self%nxh, c_intptr_t), comm%MPI_VAL, local_n, local_0, &
                                                   local_n1, local_1)
         self%nl(3) = int(local_n, ip)
         self%off(3) = int(local_0, ip)
         self%nsl = [self%nxh, self%n(3), int(local_n1, ip)]
         self%soff = [0_ip, 0_ip, int(local_1, ip)]
         self%saxis = [1_ip, 3_ip, 2_ip]
         flag_fwd = ior(flag_fwd, FFTW_MPI_TRANSPOSED_OUT)
         flag_bwd = ior(flag_bwd, FFTW_MPI_TRANSPOSED_IN)
      else if (dim == 3) then
         alloc = fftw_mpi_local_size_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                        int(self%nxh, c_intptr_t), comm%MPI_VAL, local_n, local_0)
         self%nl(3) = int(local_n, ip)
         self%off(3) = int(local_0, ip)
         call spectral_natural(self)
      else
         alloc = fftw_mpi_local_size_2d(int(self%n(2), c_intptr_t), int(self%nxh, c_intptr_t), &
                                        comm%MPI_VAL, local_n, local_0)
         self%nl(2) = int(local_n, ip)
         self%off(2) = int(local_0, ip)
         call spectral_natural(self)
      end if
      self%alloc_complex = max(int(alloc, i8), 1_i8)
      call self%alloc_field(scratch)
      if (dim == 3) then
         self%fwd = fftw_mpi_plan_dft_r2c_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                             int(self%n(1), c_intptr_t), scratch%r, scratch%c, comm%MPI_VAL, &
                                             flag_fwd)
         self%bwd = fftw_mpi_plan_dft_c2r_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                             int(self%n(1), c_intptr_t), scratch%c, scratch%r, comm%MPI_VAL, &
                                             flag_bwd)
      else
         self%fwd = fftw_mpi_plan_dft_r2c_2d(int(self%n(2), c_intptr_t), int(self%n(1), c_intptr_t), &
                                             scratch%r, scratch%c, comm%MPI_VAL, flag_fwd)
         self%bwd = fftw_mpi_plan_dft_c2r_2d(int(self%n(2), c_intptr_t), int(self%n(1), c_intptr_t), &
                                             scratch%c, scratch%r, comm%MPI_VAL, flag_bwd)
      end if
      call field_free(scratch)
   end subroutine fft_mpi_create

   !> The fftwf_mpi plans of the grid. The single-precision distribution of a grid is
   !> the double one (fftwf_mpi_local_size_* gives the same blocks for the same
   !> counts), so the fields, slabs and spectral map of the double plans serve.
   !> Collective over comm.
   subroutine slab_plan_single(self, effort, stat, errmsg)
      class(fft_mpi_t), intent(inout) :: self
      integer, intent(in) :: effort
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(c_intptr_t) :: alloc, local_n, local_0, local_n1, local_1
      integer(c_int) :: flag_fwd, flag_bwd
      type(fft_field_t) :: scratch
      logical :: same
      stat = FOLD_OK
      errmsg = ""
      if (c_associated(self%fwd_sp)) return
      flag_fwd = plan_flag(effort)
      flag_bwd = plan_flag(effort)
      if (self%dim == 3 .and. self%transposed) then
         alloc = fftwf_mpi_local_size_3d_transposed(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                                    int(self%nxh, c_intptr_t), self%comm%MPI_VAL, local_n, local_0, &
                                                    local_n1, local_1)
         same = local_n == self%nl(3) .and. local_0 == self%off(3) .and. local_n1 == self%nsl(3) &
                .and. local_1 == self%soff(3)
         flag_fwd = ior(flag_fwd, FFTW_MPI_TRANSPOSED_OUT)
         flag_bwd = ior(flag_bwd, FFTW_MPI_TRANSPOSED_IN)
      else if (self%dim == 3) then
         alloc = fftwf_mpi_local_size_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                         int(self%nxh, c_intptr_t), self%comm%MPI_VAL, local_n, local_0)
         same = local_n == self%nl(3) .and. local_0 == self%off(3)
      else
         alloc = fftwf_mpi_local_size_2d(int(self%n(2), c_intptr_t), int(self%nxh, c_intptr_t), &
                                         self%comm%MPI_VAL, local_n, local_0)
         same = local_n == self%nl(2) .and. local_0 == self%off(2)
      end if
      if (.not. same .or. alloc > self%alloc_complex) then
         stat = FOLD_INPUT_ERROR
         errmsg = "fft_mpi: the single-precision FFTW-MPI distribution differs from the double one"
         return
      end if
      call self%alloc_field(scratch)
      if (self%dim == 3) then
         self%fwd_sp = fftwf_mpi_plan_dft_r2c_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                                 int(self%n(1), c_intptr_t), scratch%rs, scratch%cs, &
                                                 self%comm%MPI_VAL, flag_fwd)
         self%bwd_sp = fftwf_mpi_plan_dft_c2r_3d(int(self%n(3), c_intptr_t), int(self%n(2), c_intptr_t), &
                                                 int(self%n(1), c_intptr_t), scratch%cs, scratch%rs, &
                                                 self%comm%MPI_VAL, flag_bwd)
      else
         self%fwd_sp = fftwf_mpi_plan_dft_r2c_2d(int(self%n(2), c_intptr_t), int(self%n(1), c_intptr_t), &
                                                 scratch%rs, scratch%cs, self%comm%MPI_VAL, flag_fwd)
         self%bwd_sp = fftwf_mpi_plan_dft_c2r_2d(int(self%n(2), c_intptr_t), int(self%n(1), c_intptr_t), &
                                                 scratch%cs, scratch%rs, self%comm%MPI_VAL, flag_bwd)
      end if
      call field_free(scratch)
      call single_plans_check(self, "fft_mpi: FFTW-MPI", stat, errmsg)
   end subroutine slab_plan_single

   subroutine slab_transform(self, f, forward, single)
      class(fft_mpi_t), intent(inout) :: self
      type(fft_field_t), intent(inout) :: f
      logical, intent(in) :: forward, single
      if (single) then
         if (forward) then
            call fftwf_mpi_execute_dft_r2c(self%fwd_sp, f%rs, f%cs)
         else
            call fftwf_mpi_execute_dft_c2r(self%bwd_sp, f%cs, f%rs)
         end if
      else if (forward) then
         call fftw_mpi_execute_dft_r2c(self%fwd, f%r, f%c)
      else
         call fftw_mpi_execute_dft_c2r(self%bwd, f%c, f%r)
      end if
   end subroutine slab_transform

   subroutine slab_sum(self, x)
      class(fft_mpi_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)
      if (size(x) > 0) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_SUM, self%comm)
   end subroutine slab_sum

   subroutine slab_max(self, x)
      class(fft_mpi_t), intent(in) :: self
      real(dp), intent(inout) :: x(:)
      if (size(x) > 0) call MPI_Allreduce(MPI_IN_PLACE, x, size(x), MPI_DOUBLE_PRECISION, MPI_MAX, self%comm)
   end subroutine slab_max

   !> Ring exchange of the slabs' boundary planes: send last to the next rank while
   !> receiving lo from the previous one, then first to the previous one while
   !> receiving hi from the next (with one rank, a copy through MPI).
   subroutine slab_z_halo(self, n, first, last, lo, hi)
      class(fft_mpi_t), intent(in) :: self
      integer(i8), intent(in) :: n
      real(dp), intent(in) :: first(n), last(n)
      real(dp), intent(out) :: lo(n), hi(n)
      integer :: prev, next
      prev = modulo(self%rank - 1, self%nranks)
      next = modulo(self%rank + 1, self%nranks)
      call MPI_Sendrecv(last, int(n), MPI_DOUBLE_PRECISION, next, 41, lo, int(n), MPI_DOUBLE_PRECISION, prev, 41, &
                        self%comm, MPI_STATUS_IGNORE)
      call MPI_Sendrecv(first, int(n), MPI_DOUBLE_PRECISION, prev, 42, hi, int(n), MPI_DOUBLE_PRECISION, next, 42, &
                        self%comm, MPI_STATUS_IGNORE)
   end subroutine slab_z_halo

   subroutine slab_destroy(self)
      class(fft_mpi_t), intent(inout) :: self
      call plans_free(self)
   end subroutine slab_destroy

end module fold_fft_mpi
