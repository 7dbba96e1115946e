!> Small 3x3 matrix kernels shared by the cell (`fold_cell`) and the grid (`fold_grid`).
module fold_mat3
   use fold_kinds, only: dp
   implicit none
   private
   public :: adjugate3

contains

   !> Adjugate of a 3x3 matrix (transposed cofactors): a adj(a) = det(a) I, so the
   !> inverse is adj(a)/det(a).
   pure function adjugate3(a) result(b)
      real(dp), intent(in) :: a(3, 3)
      real(dp) :: b(3, 3)
      b(1, 1) = a(2, 2)*a(3, 3) - a(2, 3)*a(3, 2)
      b(1, 2) = a(1, 3)*a(3, 2) - a(1, 2)*a(3, 3)
      b(1, 3) = a(1, 2)*a(2, 3) - a(1, 3)*a(2, 2)
      b(2, 1) = a(2, 3)*a(3, 1) - a(2, 1)*a(3, 3)
      b(2, 2) = a(1, 1)*a(3, 3) - a(1, 3)*a(3, 1)
      b(2, 3) = a(1, 3)*a(2, 1) - a(1, 1)*a(2, 3)
      b(3, 1) = a(2, 1)*a(3, 2) - a(2, 2)*a(3, 1)
      b(3, 2) = a(1, 2)*a(3, 1) - a(1, 1)*a(3, 2)
      b(3, 3) = a(1, 1)*a(2, 2) - a(1, 2)*a(2, 1)
   end function adjugate3

end module fold_mat3
