!> O(N) neighbour search under the sheared (Lees-Edwards) periodic images.
!>
!> The primary cell is cut into nb(1) x nb(2) x nb(3) bins of width >= rc (the
!> interaction range). A pair closer than rc (minimum image) then sits in bins whose
!> y (and z) rows differ by at most one. In x the search window is computed from the
!> query position itself: [x - rc, x + rc] covers at most three bins. A neighbour row
!> reached across the upper y-face is the image row displaced by +s (lattice vector
!> a2 = (s, Ly, 0)), so its window is shifted to [x - s - rc, x - s + rc]; across the
!> lower face to [x + s - rc, x + s + rc] (Allen & Tildesley 2017, Computer
!> Simulation of Liquids, 2nd ed., section 5.3 and appendix on Lees-Edwards cells).
!> Directions with fewer than three bins are scanned whole. The candidates are a
!> superset of the neighbours; callers test the minimum-image distance, which is
!> unique when every periodic edge exceeds 2 rc (checked in cell_list_setup, unless
!> at most one particle is inserted: no pair, no check, any particle size).
!>
!> Deforming lattice (elongational and general flows, `fold_cell`): the bins are
!> taken in the fractional coordinates f = B^-1 (x - origin) mod 1 of the reduced
!> basis B, nb(k) = floor(h_k / rc) bins along b_k (h_k the cell thickness along
!> b_k). Two points closer than rc differ in f_k by at most rc/h_k <= 1/nb(k) (the
!> fractional coordinate is the distance to the lattice plane over h_k), so their bins
!> differ by at most one in every direction (mod nb): the usual 3^dim stencil of a
!> triclinic cell list. Every non-zero lattice vector is at least min h_k long, so
!> h_k > 2 rc keeps the image within rc unique; a thinner cell is refused with the
!> time it was reached (the run driver then stops cleanly).
!>
!> Bin-sorted search (cell_list_sort, cell_list_image_stencil; used by fold_contacts):
!> a counting sort puts the particles of every bin in consecutive slots with their
!> wrapped positions, and the stencil of a query gives, with each bin, the lattice
!> translation of its images next to the query, so a caller reads the neighbours
!> from a few contiguous stretches of memory and gets their image without a minimum
!> image per candidate. Only for sheared / fixed cells with >= 3 bins per periodic
!> direction (every stencil bin then distinct); other cells use the chained lists.
module fold_cell_list
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   use fold_cell, only: cell_t, cell_min_image, cell_deforming, FOLD_FLOW_PLANAR_KR
   implicit none
   private

   !> Bins of a cell list; particles are chained through head/next.
   type, public :: cell_list_t
      !> Interaction range the bins were sized for [m]
      real(dp) :: rc = 0.0_dp
      !> Number of bins per direction
      integer(ip) :: nb(3) = 1
      !> Bin widths (>= rc) [m]
      real(dp) :: w(3) = 1.0_dp
      !> First particle of each bin (0 = empty), bins numbered 1..product(nb)
      integer(ip), allocatable :: head(:)
      !> Next particle in the same bin (0 = end)
      integer(ip), allocatable :: next(:)
   end type cell_list_t

   !> Particles sorted by bin (counting sort): slots first(b) .. first(b+1) - 1 hold the
   !> particles of bin b in increasing index order, so a bin's neighbours are read from
   !> a few contiguous stretches of memory instead of from all over the particle arrays.
   type, public :: bin_sort_t
      !> First slot of every bin, first(nbins + 1) = n + 1
      integer(ip), allocatable :: first(:)
      !> Particle index held by every slot
      integer(ip), allocatable :: id(:)
      !> Wrapped position of every slot (3, n), unused components 0 [m]
      real(dp), allocatable :: xw(:, :)
   end type bin_sort_t

   !> Most bins an image stencil can hold (x windows of at most 4 bins, 3 rows in y, z)
   integer, parameter, public :: STENCIL_MAX = 36

   public :: cell_list_setup, cell_list_insert, cell_list_build, cell_list_candidates
   public :: neighbour_pairs, cell_list_sort, cell_list_has_image_stencil, cell_list_image_stencil

contains

   !> Size the bins for range rc and capacity nmax; checks that every periodic edge
   !> is longer than 2 rc so that at most one image of a particle is within rc
   !> (skipped for nmax <= 1: a single particle has no pair; its own images move with
   !> it and never collide, so it may be as large as the cell allows).
   subroutine cell_list_setup(cl, cell, rc, nmax, stat, errmsg)
      type(cell_list_t), intent(out) :: cl
      type(cell_t), intent(in) :: cell
      !> Interaction range (> 0) [m]
      real(dp), intent(in) :: rc
      !> Largest particle index that will be inserted
      integer(ip), intent(in) :: nmax
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer :: d

      stat = FOLD_INPUT_ERROR
      errmsg = ""
      if (.not. (rc > 0.0_dp)) then
         write (errmsg, '(a,es10.3)') "cell_list: interaction range must be > 0, got ", rc
         return
      end if
      cl%rc = rc
      cl%nb = 1
      cl%w = 1.0_dp
      if (nmax <= 1) then
         ! at most one particle: there is no pair, so no minimum image to make unique.
         ! A particle never interacts with its own periodic images (a rigid particle
         ! and its images move together), so any particle size is allowed: one bin.
         if (.not. cell_deforming(cell)) cl%w(1:cell%dim) = cell%lengths(1:cell%dim)
      else if (cell_deforming(cell)) then
         ! bins along the reduced lattice vectors; the 1e-9 margin keeps a pair at
         ! distance exactly rc within the stencil despite round-off in f
         do d = 1, cell%dim
            if (.not. (cell%thickness(d) > 2.0_dp*rc)) then
               write (errmsg, '(a,es10.3,a,i0,a,es10.3,a,es12.5,a)') "cell_list: the deformed periodic cell is only ", &
                  cell%thickness(d), " thick along reduced lattice vector ", d, &
                  ", it must exceed twice the interaction range (2*", rc, ") at t = ", cell%time, &
                  trim(merge(": enlarge the cell or shrink the particles"//repeat(" ", 36), &
                             ": without a reproducible remap (uniaxial or general flow) the run cannot go on", &
                             cell%flow == FOLD_FLOW_PLANAR_KR))
               return
            end if
         end do
         do d = 1, cell%dim
            cl%nb(d) = max(1, int(cell%thickness(d)/(rc*(1.0_dp + 1.0e-9_dp))))
            cl%w(d) = 1.0_dp/cl%nb(d)
         end do
      else
         do d = 1, cell%dim
            if (d == 2 .and. cell%walls) cycle
            if (.not. (cell%lengths(d) > 2.0_dp*rc)) then
               write (errmsg, '(a,i0,a,es10.3,a,es10.3,a)') "cell_list: cell edge ", d, " (", cell%lengths(d), &
                  ") must exceed twice the interaction range (2*", rc, "): enlarge the cell or shrink the particles"
               return
            end if
         end do
         do d = 1, cell%dim
            cl%nb(d) = max(1, int(cell%lengths(d)/rc))
            cl%w(d) = cell%lengths(d)/cl%nb(d)
         end do
      end if
      allocate (cl%head(product(cl%nb)), cl%next(max(nmax, 0)))
      cl%head = 0
      cl%next = 0
      stat = FOLD_OK
   end subroutine cell_list_setup

   !> Bin coordinates (0-based) of a position, after wrapping into the primary cell.
   pure subroutine bin_of(cl, cell, x, ib, xw)
      type(cell_list_t), intent(in) :: cl
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: x(:)
      integer, intent(out) :: ib(3)
      !> Wrapped position (3 components, unused ones 0)
      real(dp), intent(out) :: xw(3)
      real(dp) :: ny
      integer :: d

      xw = 0.0_dp
      if (cell_deforming(cell)) then
         ! xw: fractional coordinates in [0, 1) of the reduced basis
         xw(1:cell%dim) = matmul(cell%dual(1:cell%dim, 1:cell%dim), x(1:cell%dim) - cell%origin(1:cell%dim))
         xw(1:cell%dim) = xw(1:cell%dim) - floor(xw(1:cell%dim))
         ib = 0
         do d = 1, cell%dim
            ib(d) = min(max(int(floor(xw(d)*cl%nb(d))), 0), cl%nb(d) - 1)
         end do
         return
      end if
      xw(1:cell%dim) = x(1:cell%dim)
      if (.not. cell%walls) then
         ny = floor(xw(2)/cell%lengths(2))
         xw(1) = xw(1) - ny*cell%shear_offset
         xw(2) = xw(2) - ny*cell%lengths(2)
      end if
      xw(1) = modulo(xw(1), cell%lengths(1))
      if (cell%dim == 3) xw(3) = modulo(xw(3), cell%lengths(3))
      ib = 0
      do d = 1, cell%dim
         ib(d) = min(max(int(floor(xw(d)/cl%w(d))), 0), cl%nb(d) - 1)
      end do
   end subroutine bin_of

   pure function bin_index(cl, ib) result(k)
      type(cell_list_t), intent(in) :: cl
      integer, intent(in) :: ib(3)
      integer :: k
      k = 1 + ib(1) + cl%nb(1)*(ib(2) + cl%nb(2)*ib(3))
   end function bin_index

   !> Bins searched along one axis: the query's bin ib and its two neighbours (`around`;
   !> wrapped or skipped by the caller), else the whole row 0 .. nb - 1.
   pure subroutine bin_span(around, ib, nb, lo, hi)
      logical, intent(in) :: around
      integer, intent(in) :: ib, nb
      integer, intent(out) :: lo, hi
      if (around) then
         lo = ib - 1
         hi = ib + 1
      else
         lo = 0
         hi = nb - 1
      end if
   end subroutine bin_span

   !> Append the particles of bin b to cand(nc+1:), in list order.
   pure subroutine append_bin(cl, b, cand, nc)
      type(cell_list_t), intent(in) :: cl
      integer, intent(in) :: b
      integer(ip), intent(inout) :: cand(:)
      integer(ip), intent(inout) :: nc
      integer(ip) :: k
      k = cl%head(b)
      do while (k > 0)
         nc = nc + 1
         cand(nc) = k
         k = cl%next(k)
      end do
   end subroutine append_bin

   !> Insert particle k at position x (any image).
   pure subroutine cell_list_insert(cl, cell, k, x)
      type(cell_list_t), intent(inout) :: cl
      type(cell_t), intent(in) :: cell
      integer(ip), intent(in) :: k
      real(dp), intent(in) :: x(:)
      integer :: ib(3), b
      real(dp) :: xw(3)
      call bin_of(cl, cell, x, ib, xw)
      b = bin_index(cl, ib)
      cl%next(k) = cl%head(b)
      cl%head(b) = k
   end subroutine cell_list_insert

   !> Build a cell list of all n particles x(dim, n) for range rc.
   subroutine cell_list_build(cl, cell, x, rc, stat, errmsg)
      type(cell_list_t), intent(out) :: cl
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(in) :: rc
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: k
      call cell_list_setup(cl, cell, rc, int(size(x, 2), ip), stat, errmsg)
      if (stat /= FOLD_OK) return
      do k = 1, int(size(x, 2), ip)
         call cell_list_insert(cl, cell, k, x(:, k))
      end do
   end subroutine cell_list_build

   !> All particles in the bins that can hold a neighbour (within rc) of position xq.
   !> cand must have room for every inserted particle; nc returns the count.
   pure subroutine cell_list_candidates(cl, cell, xq, cand, nc)
      type(cell_list_t), intent(in) :: cl
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: xq(:)
      integer(ip), intent(inout) :: cand(:)
      integer(ip), intent(out) :: nc
      integer :: ib(3), jy, jz, jx, jxlo, jxhi, b, iy_lo, iy_hi, iz_lo, iz_hi, jyw, jzw, jxw, lo(3), hi(3), d
      real(dp) :: xw(3), shift

      nc = 0
      call bin_of(cl, cell, xq, ib, xw)
      if (cell_deforming(cell)) then
         ! triclinic 3^dim stencil (whole rows where fewer than three bins)
         lo = 0
         hi = 0
         do d = 1, cell%dim
            call bin_span(cl%nb(d) >= 3, ib(d), cl%nb(d), lo(d), hi(d))
         end do
         do jz = lo(3), hi(3)
            do jy = lo(2), hi(2)
               do jx = lo(1), hi(1)
                  b = bin_index(cl, [modulo(jx, cl%nb(1)), modulo(jy, cl%nb(2)), modulo(jz, cl%nb(3))])
                  call append_bin(cl, b, cand, nc)
               end do
            end do
         end do
         return
      end if
      call bin_span(cl%nb(2) >= 3 .or. cell%walls, ib(2), cl%nb(2), iy_lo, iy_hi)
      call bin_span(cell%dim == 3 .and. cl%nb(3) >= 3, ib(3), cl%nb(3), iz_lo, iz_hi)
      do jy = iy_lo, iy_hi
         shift = 0.0_dp
         jyw = jy
         if (jy < 0) then
            if (cell%walls) cycle
            jyw = jy + cl%nb(2)
            shift = cell%shear_offset    ! images of the top row sit at x - s
         else if (jy >= cl%nb(2)) then
            if (cell%walls) cycle
            jyw = jy - cl%nb(2)
            shift = -cell%shear_offset   ! images of the bottom row sit at x + s
         end if
         if (cl%nb(1) >= 3 .and. (cl%nb(2) >= 3 .or. cell%walls)) then
            jxlo = int(floor((xw(1) + shift - cl%rc)/cl%w(1)))
            jxhi = int(floor((xw(1) + shift + cl%rc)/cl%w(1)))
         else
            jxlo = 0
            jxhi = cl%nb(1) - 1
         end if
         do jz = iz_lo, iz_hi
            jzw = modulo(jz, cl%nb(3))
            do jx = jxlo, jxhi
               jxw = modulo(jx, cl%nb(1))
               b = bin_index(cl, [jxw, jyw, jzw])
               call append_bin(cl, b, cand, nc)
            end do
         end do
      end do
   end subroutine cell_list_candidates

   !> Counting sort of the n particles x(dim, n) by bin (O(N + bins)), with their
   !> wrapped positions. cl must have been set up (cell_list_setup) for this cell.
   subroutine cell_list_sort(cl, cell, x, bs)
      type(cell_list_t), intent(in) :: cl
      type(cell_t), intent(in) :: cell
      real(dp), intent(in) :: x(:, :)
      type(bin_sort_t), intent(inout) :: bs
      integer(ip) :: n, nbins, k, b, slot
      integer(ip), allocatable :: bin(:), fill(:)
      real(dp), allocatable :: xw(:, :)
      integer :: ib(3)

      n = int(size(x, 2), ip)
      nbins = int(product(cl%nb), ip)
      if (allocated(bs%first)) deallocate (bs%first, bs%id, bs%xw)
      allocate (bs%first(nbins + 1), bs%id(n), bs%xw(3, n), bin(n), xw(3, n), fill(nbins))
      bs%first = 0
      do k = 1, n
         call bin_of(cl, cell, x(:, k), ib, xw(:, k))
         bin(k) = bin_index(cl, ib)
         bs%first(bin(k)) = bs%first(bin(k)) + 1
      end do
      ! counts -> first slots (exclusive prefix sum)
      slot = 1
      do b = 1, nbins
         fill(b) = slot
         slot = slot + bs%first(b)
         bs%first(b) = fill(b)
      end do
      bs%first(nbins + 1) = n + 1
      do k = 1, n
         slot = fill(bin(k))
         fill(bin(k)) = slot + 1
         bs%id(slot) = k
         bs%xw(:, slot) = xw(:, k)
      end do
   end subroutine cell_list_sort

   !> True when cell_list_image_stencil applies: a sheared (or fixed) periodic cell,
   !> or one with walls, with at least three bins along every periodic direction, so
   !> that every bin of a stencil is a distinct bin reached by exactly one image.
   !> Otherwise (small cells, deforming lattices) callers use cell_list_candidates
   !> and the minimum image of every candidate.
   pure logical function cell_list_has_image_stencil(cl, cell) result(ok)
      type(cell_list_t), intent(in) :: cl
      type(cell_t), intent(in) :: cell
      ok = .not. cell_deforming(cell) .and. cl%nb(1) >= 3 .and. (cell%walls .or. cl%nb(2) >= 3) &
           .and. (cell%dim == 2 .or. cl%nb(3) >= 3)
   end function cell_list_has_image_stencil

   !> The bins of cell_list_candidates for a query at wrapped position xw (from
   !> bin_sort_t) together with the lattice translation of each: a particle at wrapped
   !> position xw_b in bins(k) has the image xw_b + shift(:, k) next to the query, and
   !> that image is its minimum image whenever the pair is closer than rc (up to the
   !> round-off of the wrapping). The same windows as cell_list_candidates: rows in y
   !> (and z) differ by at most one, a row across the sheared y-face is read in the
   !> window shifted by -/+s and its images are translated by +/-a2 = +/-(s, Ly, 0).
   !> Requires cell_list_has_image_stencil.
   pure subroutine cell_list_image_stencil(cl, cell, xw, nst, bins, shift)
      type(cell_list_t), intent(in) :: cl
      type(cell_t), intent(in) :: cell
      !> Wrapped query position (3) [m]
      real(dp), intent(in) :: xw(3)
      !> Number of stencil bins
      integer, intent(out) :: nst
      !> Bin numbers (STENCIL_MAX)
      integer(ip), intent(out) :: bins(:)
      !> Lattice translation of the images in each bin (3, STENCIL_MAX) [m]
      real(dp), intent(out) :: shift(:, :)
      integer :: ib(3), jx, jy, jz, jxlo, jxhi, jxw, jyw, jzw, iz_lo, iz_hi, mx, my, mz
      real(dp) :: xshift

      nst = 0
      do jx = 1, cell%dim
         ib(jx) = min(max(int(floor(xw(jx)/cl%w(jx))), 0), cl%nb(jx) - 1)
      end do
      if (cell%dim == 2) ib(3) = 0
      iz_lo = 0
      iz_hi = 0
      if (cell%dim == 3) then
         iz_lo = ib(3) - 1
         iz_hi = ib(3) + 1
      end if
      do jy = ib(2) - 1, ib(2) + 1
         jyw = jy
         my = 0
         if (jy < 0) then
            if (cell%walls) cycle
            jyw = jy + cl%nb(2)
            my = -1
         else if (jy >= cl%nb(2)) then
            if (cell%walls) cycle
            jyw = jy - cl%nb(2)
            my = 1
         end if
         ! images of the row across the top face sit at x + s, i.e. window x - s
         xshift = -my*cell%shear_offset
         jxlo = int(floor((xw(1) + xshift - cl%rc)/cl%w(1)))
         jxhi = int(floor((xw(1) + xshift + cl%rc)/cl%w(1)))
         do jz = iz_lo, iz_hi
            call wrap_bin(jz, cl%nb(3), jzw, mz)
            do jx = jxlo, min(jxhi, jxlo + 3)
               call wrap_bin(jx, cl%nb(1), jxw, mx)
               nst = nst + 1
               bins(nst) = 1 + jxw + cl%nb(1)*(jyw + cl%nb(2)*jzw)
               shift(1, nst) = mx*cell%lengths(1) + my*cell%shear_offset
               shift(2, nst) = my*cell%lengths(2)
               shift(3, nst) = mz*cell%lengths(3)
            end do
         end do
      end do
   end subroutine cell_list_image_stencil

   !> All pairs i < j whose minimum-image centre distance is < rc, either by the
   !> O(N^2) double loop (use_cells = false, the reference) or with the cell list.
   !> pairs(:, 1:npairs) is sorted by (i, j). If more than size(pairs, 2) pairs
   !> exist, npairs returns the true count and stat = FOLD_INPUT_ERROR.
   subroutine neighbour_pairs(cell, x, rc, use_cells, pairs, npairs, stat, errmsg)
      type(cell_t), intent(in) :: cell
      !> Centres x(dim, n) [m]
      real(dp), intent(in) :: x(:, :)
      !> Range [m]
      real(dp), intent(in) :: rc
      logical, intent(in) :: use_cells
      integer(ip), intent(out) :: pairs(:, :)
      integer(ip), intent(out) :: npairs
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      type(cell_list_t) :: cl
      integer(ip) :: i, j, n, nc, c
      integer(ip), allocatable :: cand(:)
      real(dp) :: dx(cell%dim)

      n = int(size(x, 2), ip)
      npairs = 0
      pairs = 0
      call cell_list_build(cl, cell, x, rc, stat, errmsg)
      if (stat /= FOLD_OK) return
      if (use_cells) then
         allocate (cand(n))
         do i = 1, n
            call cell_list_candidates(cl, cell, x(:, i), cand, nc)
            call sort_int(cand(1:nc))
            do c = 1, nc
               j = cand(c)
               if (j <= i) cycle
               dx = x(:, i) - x(:, j)
               call cell_min_image(cell, dx)
               if (norm2(dx) < rc) call push(i, j)
            end do
         end do
      else
         do i = 1, n
            do j = i + 1, n
               dx = x(:, i) - x(:, j)
               call cell_min_image(cell, dx)
               if (norm2(dx) < rc) call push(i, j)
            end do
         end do
      end if
      if (npairs > size(pairs, 2)) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0,a,i0)') "neighbour_pairs: found ", npairs, " pairs, room for only ", size(pairs, 2)
      end if
   contains
      subroutine push(a, b)
         integer(ip), intent(in) :: a, b
         npairs = npairs + 1
         if (npairs <= size(pairs, 2)) pairs(:, npairs) = [a, b]
      end subroutine push
   end subroutine neighbour_pairs

   !> The bin jw in 0 ... nb - 1 of bin j of the unwrapped lattice and its image m
   !> (j = jw + m nb); wrapped only at the faces (integer divisions per bin cost more
   !> than the rest).
   pure subroutine wrap_bin(j, nb, jw, m)
      integer, intent(in) :: j, nb
      integer, intent(out) :: jw, m
      jw = j
      m = 0
      if (j < 0 .or. j >= nb) then
         jw = modulo(j, nb)
         m = (j - jw)/nb
      end if
   end subroutine wrap_bin

   !> Insertion sort (candidate lists are short).
   pure subroutine sort_int(a)
      integer(ip), intent(inout) :: a(:)
      integer :: i, j
      integer(ip) :: key
      do i = 2, size(a)
         key = a(i)
         j = i - 1
         do while (j >= 1)
            if (a(j) <= key) exit
            a(j + 1) = a(j)
            j = j - 1
         end do
         a(j + 1) = key
      end do
   end subroutine sort_int

end module fold_cell_list
