!> The 3N×3N semismooth Newton system A X = B of DESIGN.md §1, in block order (X1, X2, X3):
!>
!>     [ μ1 S   0    −D ]          [ F                 ]
!>     [ 0     μ2 S   D ]  X  =    [ F2                ]
!>     [ J1    −J1   J3 ]          [ J_C X_old − C(X_old) ]
!>
!> The pattern is fixed once: every C-function row holds its three diagonal entries whichever
!> are zero, so the symbolic factorization (and later ILU(0)) survives all Newton steps.
module twomem_newton_system
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   use twomem_fem_discrete, only: discrete_problem_t
   implicit none
   private

   public :: newton_system_t

   type :: newton_system_t
      integer(ip) :: n = 0
      type(csr_t) :: a
      !> positions in a%val of the C-row entries (X1, X2, X3) of each vertex, (3, n)
      integer(ip), allocatable :: c_pos(:, :)
      !> [F1; F2], the linear part of the right-hand side
      real(dp), allocatable :: f(:)
   contains
      procedure :: init => system_init
      procedure :: set_jacobian
      procedure :: apply_e
   end type newton_system_t

contains

   subroutine system_init(self, p)
      class(newton_system_t), intent(inout) :: self
      type(discrete_problem_t), intent(in) :: p

      integer(ip) :: n, i, m, k
      integer(ip), allocatable :: row_ptr(:), col(:)

      n = p%n
      self%n = n
      allocate (row_ptr(3*n + 1), col(2*p%stiffness%nnz() + 5*n))
      k = 0
      row_ptr(1) = 1
      do i = 1, n
         do m = p%stiffness%row_ptr(i), p%stiffness%row_ptr(i + 1) - 1
            k = k + 1
            col(k) = p%stiffness%col(m)
         end do
         k = k + 1
         col(k) = 2*n + i
         row_ptr(i + 1) = k + 1
      end do
      do i = 1, n
         do m = p%stiffness%row_ptr(i), p%stiffness%row_ptr(i + 1) - 1
            k = k + 1
            col(k) = n + p%stiffness%col(m)
         end do
         k = k + 1
         col(k) = 2*n + i
         row_ptr(n + i + 1) = k + 1
      end do
      do i = 1, n
         col(k + 1:k + 3) = [i, n + i, 2*n + i]
         k = k + 3
         row_ptr(2*n + i + 1) = k + 1
      end do
      call self%a%init_pattern(row_ptr, col(1:k))

      ! the two linear block rows never change
      do i = 1, n
         do m = p%stiffness%row_ptr(i), p%stiffness%row_ptr(i + 1) - 1
            self%a%val(self%a%find(i, p%stiffness%col(m))) = p%mu1*p%stiffness%val(m)
            self%a%val(self%a%find(n + i, n + p%stiffness%col(m))) = p%mu2*p%stiffness%val(m)
         end do
         self%a%val(self%a%find(i, 2*n + i)) = -p%mass(i)
         self%a%val(self%a%find(n + i, 2*n + i)) = p%mass(i)
      end do
      allocate (self%c_pos(3, n))
      do i = 1, n
         self%c_pos(:, i) = [self%a%find(2*n + i, i), self%a%find(2*n + i, n + i), &
                             self%a%find(2*n + i, 2*n + i)]
      end do
      self%f = [p%f1, p%f2]
   end subroutine system_init

   !> Put the C-function Jacobian (∂C/∂a, ∂C/∂b per vertex) into the third block row.
   subroutine set_jacobian(self, da, db)
      class(newton_system_t), intent(inout) :: self
      real(dp), intent(in) :: da(:), db(:)

      integer(ip) :: i

      do i = 1, self%n
         self%a%val(self%c_pos(1, i)) = da(i)
         self%a%val(self%c_pos(2, i)) = -da(i)
         self%a%val(self%c_pos(3, i)) = db(i)
      end do
   end subroutine set_jacobian

   !> E X: the two linear block rows applied to X (length 2n).
   subroutine apply_e(self, x, ex)
      class(newton_system_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: ex(:)

      integer(ip) :: i, k
      real(dp) :: s

      !$omp parallel do default(none) shared(self, x, ex) private(i, k, s) schedule(static)
      do i = 1, 2*self%n
         s = 0.0_dp
         do k = self%a%row_ptr(i), self%a%row_ptr(i + 1) - 1
            s = s + self%a%val(k)*x(self%a%col(k))
         end do
         ex(i) = s
      end do
      !$omp end parallel do
   end subroutine apply_e
end module twomem_newton_system
