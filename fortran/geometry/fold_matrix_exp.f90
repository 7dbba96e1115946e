!> Matrix exponential of a 3x3 matrix (the propagator exp(t G) of a constant
!> velocity gradient: lattice deformation in `fold_cell`, Jeffery's exact step in
!> `fold_jeffery_step`).
module fold_matrix_exp
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use fold_kinds, only: dp
   implicit none
   private
   public :: expm3

contains

   !> Matrix exponential of a 3x3 matrix: Taylor series of A/2^s to 20 terms
   !> (remainder < 0.5^21/21! relative) followed by s squarings (Moler & Van Loan
   !> 2003, SIAM Rev. 45:3, method 3). A matrix of norm > 1e100 or with a NaN gives
   !> NaN, so callers' blow-up checks see it.
   pure function expm3(A) result(E)
      real(dp), intent(in) :: A(3, 3)
      real(dp) :: E(3, 3)
      real(dp) :: B(3, 3), term(3, 3), nrm
      integer :: s, k

      nrm = maxval(sum(abs(A), dim=1))
      if (.not. (nrm <= 1.0e100_dp)) then
         E = ieee_value(1.0_dp, ieee_quiet_nan)
         return
      end if
      s = 0
      if (nrm > 0.5_dp) s = ceiling(log(nrm/0.5_dp)/log(2.0_dp))
      B = A/2.0_dp**s
      E = 0.0_dp
      term = 0.0_dp
      do k = 1, 3
         E(k, k) = 1.0_dp
         term(k, k) = 1.0_dp
      end do
      do k = 1, 20
         term = matmul(term, B)/real(k, dp)
         E = E + term
      end do
      do k = 1, s
         E = matmul(E, E)
      end do
   end function expm3

end module fold_matrix_exp
