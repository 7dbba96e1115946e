! Thin f2py layer over fold_orientation_stats: plain external subroutines with
! explicit-shape arguments, so the hand-kept stats.pyf can hide the sizes.
subroutine fold_orientation_moments(dim, n, p, w, a2, a4, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_orientation_stats, only: orientation_moments
   implicit none
   integer(ip), intent(in) :: dim, n
   real(dp), intent(in) :: p(dim, n), w(n)
   real(dp), intent(out) :: a2(dim, dim), a4(dim, dim, dim, dim)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   call orientation_moments(dim, n, p, w, a2, a4, stat, errmsg)
end subroutine fold_orientation_moments

subroutine fold_orientation_moments_batch(dim, n, nt, p, w, a2, a4, stat, errmsg)
   use fold_kinds, only: dp, ip, msg_len
   use fold_orientation_stats, only: orientation_moments_batch
   implicit none
   integer(ip), intent(in) :: dim, n, nt
   real(dp), intent(in) :: p(dim, n, nt), w(n)
   real(dp), intent(out) :: a2(dim, dim, nt), a4(dim, dim, dim, dim, nt)
   integer, intent(out) :: stat
   character(len=msg_len), intent(out) :: errmsg
   call orientation_moments_batch(dim, n, nt, p, w, a2, a4, stat, errmsg)
end subroutine fold_orientation_moments_batch
