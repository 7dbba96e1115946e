!> A seeded, reproducible random stream held in a derived type (no global state).
!>
!> MRG32k3a combined multiple-recursive generator (L'Ecuyer 1999, Oper. Res.
!> 47:159-164), period ~2^191, computed in double precision where every product is
!> below 2^53 and therefore exact: the same seed gives the same stream on every
!> compiler and platform (unlike the intrinsic random_number). The six state words
!> are filled from the seed with the MINSTD recursion x <- 48271 x mod (2^31 - 1)
!> (Park, Miller & Stockmeyer 1993), then 64 outputs are discarded.
module fold_random
   use fold_kinds, only: dp, i8
   implicit none
   private

   real(dp), parameter :: m1 = 4294967087.0_dp, m2 = 4294944443.0_dp
   real(dp), parameter :: a12 = 1403580.0_dp, a13n = 810728.0_dp
   real(dp), parameter :: a21 = 527612.0_dp, a23n = 1370589.0_dp
   real(dp), parameter :: norm = 1.0_dp/(m1 + 1.0_dp)

   !> Generator state.
   type, public :: rng_t
      real(dp) :: s1(3) = 12345.0_dp
      real(dp) :: s2(3) = 12345.0_dp
   end type rng_t

   public :: rng_seed, rng_uniform

contains

   !> Initialise the stream from any integer seed.
   pure subroutine rng_seed(rng, seed)
      type(rng_t), intent(out) :: rng
      integer(i8), intent(in) :: seed
      integer(i8) :: x
      integer :: k
      real(dp) :: u
      x = modulo(seed, 2147483646_i8) + 1_i8
      do k = 1, 3
         x = modulo(48271_i8*x, 2147483647_i8)
         rng%s1(k) = real(modulo(x, 4294967087_i8 - 1_i8) + 1_i8, dp)
         x = modulo(48271_i8*x, 2147483647_i8)
         rng%s2(k) = real(modulo(x, 4294944443_i8 - 1_i8) + 1_i8, dp)
      end do
      do k = 1, 64
         call rng_uniform(rng, u)
      end do
   end subroutine rng_seed

   !> One uniform deviate in (0, 1).
   pure subroutine rng_uniform(rng, u)
      type(rng_t), intent(inout) :: rng
      real(dp), intent(out) :: u
      real(dp) :: p1, p2
      integer(i8) :: kk
      p1 = a12*rng%s1(2) - a13n*rng%s1(1)
      kk = int(p1/m1, i8)
      p1 = p1 - kk*m1
      if (p1 < 0.0_dp) p1 = p1 + m1
      rng%s1(1) = rng%s1(2); rng%s1(2) = rng%s1(3); rng%s1(3) = p1
      p2 = a21*rng%s2(3) - a23n*rng%s2(1)
      kk = int(p2/m2, i8)
      p2 = p2 - kk*m2
      if (p2 < 0.0_dp) p2 = p2 + m2
      rng%s2(1) = rng%s2(2); rng%s2(2) = rng%s2(3); rng%s2(3) = p2
      if (p1 > p2) then
         u = (p1 - p2)*norm
      else
         u = (p1 - p2 + m1)*norm
      end if
   end subroutine rng_uniform

end module fold_random
