!> Jacobi (diagonal) preconditioning, z = r / diag(A): the cheapest preconditioner and the
!> baseline the others are measured against. Both setup and apply are one pass over the rows
!> with no coupling between them, so both are threaded. On the Newton matrix an active
!> Newton-min C-row has no λ-λ entry (J3 = 0, the row is [1, −1, 0] on (X1, X2, X3)); there the
!> preconditioner uses 1 instead of 1/0. Its rows are of unit size already and no other
!> diagonal entry gives a meaningful scale for them, so leaving them unscaled is the neutral
!> choice. The same rule covers any zero diagonal and a diagonal entry missing from the pattern.
module twomem_linalg_jacobi
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: preconditioner_t
   implicit none
   private

   public :: jacobi_preconditioner_t

   type, extends(preconditioner_t) :: jacobi_preconditioner_t
      private
      !> 1 / a_ii, or 1 where a_ii = 0
      real(dp), allocatable :: inv_diag(:)
   contains
      procedure :: setup => jacobi_setup
      procedure :: apply => jacobi_apply
      procedure :: free => jacobi_free
   end type jacobi_preconditioner_t

contains

   !> Never fails: a zero or missing diagonal entry is taken as 1 (see the module comment).
   subroutine jacobi_setup(self, a, err)
      class(jacobi_preconditioner_t), intent(inout) :: self
      type(csr_t), intent(in) :: a
      type(error_t), allocatable, intent(out) :: err

      if (allocated(self%inv_diag)) then
         if (size(self%inv_diag) /= a%n) deallocate (self%inv_diag)
      end if
      if (.not. allocated(self%inv_diag)) allocate (self%inv_diag(a%n))
      call invert_diagonal(a, self%inv_diag)
   end subroutine jacobi_setup

   subroutine invert_diagonal(a, inv_diag)
      type(csr_t), intent(in) :: a
      real(dp), intent(out) :: inv_diag(:)

      integer(ip) :: i, k

      !$omp parallel do default(none) shared(a, inv_diag) private(i, k) schedule(static)
      do i = 1, a%n
         k = a%find(i, i)
         inv_diag(i) = 1.0_dp
         if (k > 0) then
            if (a%val(k) /= 0.0_dp) inv_diag(i) = 1.0_dp/a%val(k)
         end if
      end do
      !$omp end parallel do
   end subroutine invert_diagonal

   !> z = D⁻¹ r; the identity before the first setup.
   subroutine jacobi_apply(self, r, z)
      class(jacobi_preconditioner_t), intent(inout) :: self
      real(dp), intent(in) :: r(:)
      real(dp), intent(out) :: z(:)

      if (.not. allocated(self%inv_diag)) then
         z = r
         return
      end if
      call scale(self%inv_diag, r, z)
   end subroutine jacobi_apply

   subroutine scale(d, r, z)
      real(dp), intent(in) :: d(:), r(:)
      real(dp), intent(out) :: z(:)

      integer(ip) :: i

      !$omp parallel do default(none) shared(d, r, z) private(i) schedule(static)
      do i = 1, size(d, kind=ip)
         z(i) = d(i)*r(i)
      end do
      !$omp end parallel do
   end subroutine scale

   subroutine jacobi_free(self)
      class(jacobi_preconditioner_t), intent(inout) :: self

      if (allocated(self%inv_diag)) deallocate (self%inv_diag)
   end subroutine jacobi_free
end module twomem_linalg_jacobi
