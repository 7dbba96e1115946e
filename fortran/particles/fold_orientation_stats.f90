!> Orientation moments of a particle population: a2 = <p p>, a4 = <p p p p>.
!>
!> a2_ij = sum_k w_k p_ki p_kj / sum_k w_k  and  a4_ijkl likewise (Advani & Tucker 1987,
!> J. Rheol. 31:751). Both are fully symmetric by construction; only the independent
!> components of a4 are accumulated and then copied to every permutation, which
!> keeps the result exactly symmetric in floating point.
module fold_orientation_stats
   use fold_kinds, only: dp, ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR, FOLD_NUMERICAL
   use fold_check, only: check_dim
   implicit none
   private
   public :: orientation_moments, orientation_moments_batch

contains

   !> Second- and fourth-order orientation tensors of one snapshot.
   pure subroutine orientation_moments(dim, n, p, w, a2, a4, stat, errmsg)
      !> Spatial dimension (2 or 3)
      integer(ip), intent(in) :: dim
      !> Number of particles
      integer(ip), intent(in) :: n
      !> Unit orientation vectors p(:, k) [-]
      real(dp), intent(in) :: p(dim, n)
      !> Non-negative weights (e.g. ones, or particle volumes) [any unit]
      real(dp), intent(in) :: w(n)
      !> Second-order orientation tensor [-]
      real(dp), intent(out) :: a2(dim, dim)
      !> Fourth-order orientation tensor [-]
      real(dp), intent(out) :: a4(dim, dim, dim, dim)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg

      integer(ip) :: k, i, j, l, m
      real(dp) :: wsum, v

      a2 = 0.0_dp
      a4 = 0.0_dp
      call check_dim(dim, "orientation_moments", stat, errmsg)
      if (stat /= FOLD_OK) return
      if (n < 1) then
         stat = FOLD_INPUT_ERROR
         write (errmsg, '(a,i0)') "orientation_moments: need at least one particle, got n = ", n
         return
      end if
      if (any(w < 0.0_dp)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "orientation_moments: weights must be >= 0"
         return
      end if
      wsum = sum(w)
      if (.not. (wsum > 0.0_dp)) then
         stat = FOLD_INPUT_ERROR
         errmsg = "orientation_moments: sum of weights must be > 0"
         return
      end if

      do k = 1, n
         do i = 1, dim
            do j = i, dim
               a2(i, j) = a2(i, j) + w(k)*p(i, k)*p(j, k)
               do l = j, dim
                  do m = l, dim
                     a4(i, j, l, m) = a4(i, j, l, m) + w(k)*p(i, k)*p(j, k)*p(l, k)*p(m, k)
                  end do
               end do
            end do
         end do
      end do
      a2 = a2/wsum
      a4 = a4/wsum
      do i = 1, dim
         do j = i, dim
            a2(j, i) = a2(i, j)
            do l = j, dim
               do m = l, dim
                  v = a4(i, j, l, m)
                  call fill_permutations(a4, i, j, l, m, v)
               end do
            end do
         end do
      end do
      if (any(a4 /= a4) .or. any(a2 /= a2)) then
         stat = FOLD_NUMERICAL
         errmsg = "orientation_moments: NaN in orientation vectors"
      end if
   end subroutine orientation_moments

   !> The same for nt snapshots of the same population (time series).
   pure subroutine orientation_moments_batch(dim, n, nt, p, w, a2, a4, stat, errmsg)
      integer(ip), intent(in) :: dim, n, nt
      !> Orientation vectors p(:, k, t) [-]
      real(dp), intent(in) :: p(dim, n, nt)
      real(dp), intent(in) :: w(n)
      real(dp), intent(out) :: a2(dim, dim, nt)
      real(dp), intent(out) :: a4(dim, dim, dim, dim, nt)
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      integer(ip) :: t

      stat = FOLD_OK
      errmsg = ""
      do t = 1, nt
         call orientation_moments(dim, n, p(:, :, t), w, a2(:, :, t), a4(:, :, :, :, t), stat, errmsg)
         if (stat /= FOLD_OK) then
            write (errmsg, '(a,i0,a,a)') "snapshot ", t, ": ", trim(errmsg)
            return
         end if
      end do
   end subroutine orientation_moments_batch

   !> Copy one independent a4 component to all 24 index permutations.
   pure subroutine fill_permutations(a4, i, j, l, m, v)
      real(dp), intent(inout) :: a4(:, :, :, :)
      integer(ip), intent(in) :: i, j, l, m
      real(dp), intent(in) :: v
      integer :: q(4), perm(4, 24), s

      q = [i, j, l, m]
      perm = reshape([ &
         1, 2, 3, 4, 1, 2, 4, 3, 1, 3, 2, 4, 1, 3, 4, 2, 1, 4, 2, 3, 1, 4, 3, 2, &
         2, 1, 3, 4, 2, 1, 4, 3, 2, 3, 1, 4, 2, 3, 4, 1, 2, 4, 1, 3, 2, 4, 3, 1, &
         3, 1, 2, 4, 3, 1, 4, 2, 3, 2, 1, 4, 3, 2, 4, 1, 3, 4, 1, 2, 3, 4, 2, 1, &
         4, 1, 2, 3, 4, 1, 3, 2, 4, 2, 1, 3, 4, 2, 3, 1, 4, 3, 1, 2, 4, 3, 2, 1], [4, 24])
      do s = 1, 24
         a4(q(perm(1, s)), q(perm(2, s)), q(perm(3, s)), q(perm(4, s))) = v
      end do
   end subroutine fill_permutations
end module fold_orientation_stats
