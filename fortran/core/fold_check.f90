!> Argument checks shared by the kernels: each returns stat and a message naming the
!> routine that asked ("<where>: ...").
module fold_check
   use fold_kinds, only: ip, msg_len
   use fold_status, only: FOLD_OK, FOLD_INPUT_ERROR
   implicit none
   private
   public :: check_dim

contains

   !> stat = FOLD_OK and errmsg = "" when dim is 2 or 3; otherwise FOLD_INPUT_ERROR
   !> and "<where>: dim must be 2 or 3, got <dim>".
   pure subroutine check_dim(dim, where, stat, errmsg)
      !> Spatial dimension to check
      integer(ip), intent(in) :: dim
      !> Name of the calling routine, for the message
      character(len=*), intent(in) :: where
      integer, intent(out) :: stat
      character(len=msg_len), intent(out) :: errmsg
      stat = FOLD_OK
      errmsg = ""
      if (dim == 2 .or. dim == 3) return
      stat = FOLD_INPUT_ERROR
      write (errmsg, '(a,i0)') where//": dim must be 2 or 3, got ", dim
   end subroutine check_dim

end module fold_check
