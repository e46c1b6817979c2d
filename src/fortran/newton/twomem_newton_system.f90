!> The 3N×3N semismooth Newton system A X = B of docs/method.md §1, in block order (X1, X2, X3):
!>
!>     [ μ1 K   0    −D ]          [ F1                   ]
!>     [ 0     μ2 K   D ]  X  =    [ F2                   ]
!>     [ J1    −J1   J3 ]          [ J_C X_old − C(X_old) ]
!>
!> It is applied matrix-free from the problem's stiffness K, the lumped mass D and the
!> C-function Jacobian (J1, J3) = (∂C/∂a, ∂C/∂b): one pass over K serves both membranes, and
!> the multigrid path never stores the 3N matrix. The assembled CSR matrix exists only for the
!> solvers that factorize it (UMFPACK, ILU(0), Jacobi). Its pattern is fixed once: every
!> C-function row holds its three diagonal entries whichever are zero, so the symbolic
!> factorization (and ILU(0)'s analysis) survives all Newton steps. Both forms compute every
!> row in the same order with the same products, so they agree bit for bit. In a distributed
!> run the product sums the ranks' parts of shared rows (the problem's halo), and `dot`, the
!> inner product of Newton vectors, counts every unknown once.
module twomem_newton_system
   use twomem_base_kinds, only: dp, ip
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_operators, only: linear_operator_t, distributed_product_t
   use twomem_linalg_halo, only: halo_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_vectors, only: threaded_from
   implicit none
   private

   public :: newton_system_t, newton_operator_t

   type :: newton_system_t
      integer(ip) :: n = 0
      real(dp) :: mu1 = 1, mu2 = 1
      !> the problem's stiffness K on interior vertices (the problem outlives the system)
      type(csr_t), pointer :: k => null()
      !> the problem's lumped mass
      real(dp), pointer, contiguous :: mass(:) => null()
      !> the C-function Jacobian of the current linearization, per vertex
      real(dp), allocatable :: da(:), db(:)
      !> [F1; F2], the linear part of the right-hand side (the problem's)
      real(dp), pointer, contiguous :: f(:) => null()
      !> the assembled matrix, only when `init` was asked for it
      logical :: assembled = .false.
      type(csr_t) :: a
      !> positions in a%val of the C-row entries (X1, X2, X3) of each vertex, (3, n)
      integer(ip), allocatable :: c_pos(:, :)
      !> the unknowns' interface, and the inner product of vectors [X1; X2; X3]
      type(halo_t) :: halo
      type(distributed_product_t) :: dot
   contains
      procedure :: init => system_init
      procedure :: set_jacobian
      procedure :: apply => system_apply
      procedure :: apply_e
      procedure :: sum_squares
      procedure :: global_count
      procedure :: contact_set
      procedure :: contact_count
      procedure :: jacobian_differs
   end type newton_system_t

   !> The system as the operator GMRES iterates with.
   type, extends(linear_operator_t) :: newton_operator_t
      type(newton_system_t), pointer :: sys => null()
   contains
      procedure :: apply => operator_apply
   end type newton_operator_t

contains

   !> `assembled`: also build the CSR matrix (for UMFPACK, ILU(0) or Jacobi).
   subroutine system_init(self, p, assembled)
      class(newton_system_t), intent(out) :: self
      type(discrete_problem_t), target, intent(in) :: p
      logical, intent(in) :: assembled

      self%n = p%n
      self%mu1 = p%mu1
      self%mu2 = p%mu2
      self%k => p%stiffness
      self%mass => p%mass
      self%f => p%f
      allocate (self%da(p%n), self%db(p%n))
      self%da = 0.0_dp
      self%db = 1.0_dp
      self%halo = p%halo
      self%dot%comm = p%halo%comm
      ! a mask only where some unknown is another rank's (all true, it would change no sum)
      if (.not. all(p%halo%owned)) self%dot%owned = [p%halo%owned, p%halo%owned, p%halo%owned]
      self%assembled = assembled
      if (assembled) call assemble(self)
   end subroutine system_init

   !> Σ r(i)² over the owned unknowns of every rank, r = v, or v − minus when given, each entry
   !> times weight(i) when given (one weight per unknown, for every field); v stacks fields of the
   !> unknowns (length a multiple of n). In the order of the entries, as Fortran's sum would add
   !> them, and without a temporary for v − minus.
   real(dp) function sum_squares(self, v, minus, weight) result(s)
      class(newton_system_t), intent(in) :: self
      real(dp), intent(in) :: v(:)
      real(dp), intent(in), optional :: minus(:), weight(:)

      integer(ip) :: i, n, f
      real(dp) :: r

      n = self%n
      s = 0.0_dp
      do f = 0, size(v, kind=ip)/n - 1
         do i = 1, n
            if (.not. self%halo%owned(i)) cycle
            r = v(f*n + i)
            if (present(minus)) r = r - minus(f*n + i)
            if (present(weight)) r = weight(i)*r
            s = s + r**2
         end do
      end do
      s = self%halo%comm%sum(s)
   end function sum_squares

   !> How many unknowns over all ranks (each counted by its owner) are marked in `mask` (length
   !> n), or, given `other`, differ between mask and other. These counts run at every Newton
   !> step and GMRES check: threaded, since a serial pass over 10^6 vertices costs as much as a
   !> threaded sparse product (an integer sum: any order gives the same count).
   integer function global_count(self, mask, other) result(c)
      class(newton_system_t), intent(in) :: self
      logical, intent(in) :: mask(:)
      logical, intent(in), optional :: other(:)

      integer(ip) :: i, n

      n = self%n
      c = 0
      if (present(other)) then
         !$omp parallel do default(none) shared(self, mask, other, n) private(i) reduction(+:c) &
         !$omp schedule(static) if(n > threaded_from)
         do i = 1, n
            if ((mask(i) .neqv. other(i)) .and. self%halo%owned(i)) c = c + 1
         end do
         !$omp end parallel do
      else
         !$omp parallel do default(none) shared(self, mask, n) private(i) reduction(+:c) &
         !$omp schedule(static) if(n > threaded_from)
         do i = 1, n
            if (mask(i) .and. self%halo%owned(i)) c = c + 1
         end do
         !$omp end parallel do
      end if
      c = self%halo%comm%sum(c)
   end function global_count

   !> The contact set of iterate x = [X1; X2; X3], the vertices where X1 − X2 ≤ X3 (for Newton-min
   !> exactly those of the contact row).
   subroutine contact_set(self, x, active)
      class(newton_system_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      logical, intent(out) :: active(:)

      integer(ip) :: i, n

      n = self%n
      !$omp parallel do default(none) shared(x, active, n) private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         active(i) = in_contact(x, n, i)
      end do
      !$omp end parallel do
   end subroutine contact_set

   !> The size of x's contact set (`contact_set`) over every rank, without storing it.
   integer function contact_count(self, x) result(c)
      class(newton_system_t), intent(in) :: self
      real(dp), intent(in) :: x(:)

      integer(ip) :: i, n

      n = self%n
      c = 0
      !$omp parallel do default(none) shared(self, x, n) private(i) reduction(+:c) &
      !$omp schedule(static) if(n > threaded_from)
      do i = 1, n
         if (in_contact(x, n, i) .and. self%halo%owned(i)) c = c + 1
      end do
      !$omp end parallel do
      c = self%halo%comm%sum(c)
   end function contact_count

   !> Vertex i of n is in contact at x = [X1; X2; X3]: X1 − X2 ≤ X3 (the one definition of the set).
   pure logical function in_contact(x, n, i)
      real(dp), intent(in) :: x(:)
      integer(ip), intent(in) :: n, i

      in_contact = x(i) - x(n + i) <= x(2*n + i)
   end function in_contact

   !> Whether the Jacobian entries da, db differ anywhere, on any rank, from the system's.
   !> Collective.
   logical function jacobian_differs(self, da, db) result(differs)
      class(newton_system_t), intent(in) :: self
      real(dp), intent(in) :: da(:), db(:)

      integer(ip) :: i, n

      n = self%n
      differs = .false.
      !$omp parallel do default(none) shared(self, da, db, n) private(i) reduction(.or.:differs) &
      !$omp schedule(static) if(n > threaded_from)
      do i = 1, n
         if (da(i) /= self%da(i) .or. db(i) /= self%db(i)) differs = .true.
      end do
      !$omp end parallel do
      differs = self%halo%comm%any_true(differs)
   end function jacobian_differs

   subroutine assemble(self)
      type(newton_system_t), intent(inout) :: self

      integer(ip) :: n, i, m, k
      integer(ip), allocatable :: row_ptr(:), col(:)

      n = self%n
      allocate (row_ptr(3*n + 1), col(2*self%k%nnz() + 5*n))
      k = 0
      row_ptr(1) = 1
      do i = 1, n
         do m = self%k%row_ptr(i), self%k%row_ptr(i + 1) - 1
            k = k + 1
            col(k) = self%k%col(m)
         end do
         k = k + 1
         col(k) = 2*n + i
         row_ptr(i + 1) = k + 1
      end do
      do i = 1, n
         do m = self%k%row_ptr(i), self%k%row_ptr(i + 1) - 1
            k = k + 1
            col(k) = n + self%k%col(m)
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
         do m = self%k%row_ptr(i), self%k%row_ptr(i + 1) - 1
            self%a%val(self%a%find(i, self%k%col(m))) = self%mu1*self%k%val(m)
            self%a%val(self%a%find(n + i, n + self%k%col(m))) = self%mu2*self%k%val(m)
         end do
         ! the matrix of a distributed run is each rank's part: the stiffness of its triangles,
         ! and the nodal entries (mass, C-function rows) at the unknowns it owns
         if (.not. self%halo%owned(i)) cycle
         self%a%val(self%a%find(i, 2*n + i)) = -self%mass(i)
         self%a%val(self%a%find(n + i, 2*n + i)) = self%mass(i)
      end do
      allocate (self%c_pos(3, n))
      do i = 1, n
         self%c_pos(:, i) = [self%a%find(2*n + i, i), self%a%find(2*n + i, n + i), &
                             self%a%find(2*n + i, 2*n + i)]
      end do
      call set_jacobian(self, self%da, self%db)
   end subroutine assemble

   !> The C-function Jacobian (∂C/∂a, ∂C/∂b per vertex) of the third block row.
   subroutine set_jacobian(self, da, db)
      class(newton_system_t), intent(inout) :: self
      real(dp), intent(in) :: da(:), db(:)

      integer(ip) :: i

      self%da = da
      self%db = db
      if (.not. self%assembled) return
      do i = 1, self%n
         if (.not. self%halo%owned(i)) cycle
         self%a%val(self%c_pos(1, i)) = da(i)
         self%a%val(self%c_pos(2, i)) = -da(i)
         self%a%val(self%c_pos(3, i)) = db(i)
      end do
   end subroutine set_jacobian

   !> y = A x (length 3n). Collective.
   subroutine system_apply(self, x, y)
      class(newton_system_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      integer(ip) :: n, i

      n = self%n
      call self%apply_e(x, y(1:2*n))
      !$omp parallel do default(none) shared(self, x, y, n) private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         y(2*n + i) = self%da(i)*x(i) + (-self%da(i))*x(n + i) + self%db(i)*x(2*n + i)
      end do
      !$omp end parallel do
   end subroutine system_apply

   !> E X: the two membrane block rows applied to X (length 2n), in the order and with the
   !> products of the assembled rows (columns ascending, the D column last).
   subroutine apply_e(self, x, ex)
      class(newton_system_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: ex(:)

      integer(ip) :: n, i, m
      real(dp) :: s1, s2

      n = self%n
      !$omp parallel do default(none) shared(self, x, ex, n) private(i, m, s1, s2) schedule(static) &
      !$omp if(n > threaded_from)
      do i = 1, n
         s1 = 0.0_dp
         s2 = 0.0_dp
         do m = self%k%row_ptr(i), self%k%row_ptr(i + 1) - 1
            s1 = s1 + (self%mu1*self%k%val(m))*x(self%k%col(m))
            s2 = s2 + (self%mu2*self%k%val(m))*x(n + self%k%col(m))
         end do
         ex(i) = s1
         ex(n + i) = s2
      end do
      !$omp end parallel do
      ! the stiffness parts of shared rows summed, then the (full) lumped mass
      call self%halo%add(ex(1:n))
      call self%halo%add(ex(n + 1:2*n))
      !$omp parallel do default(none) shared(self, x, ex, n) private(i) schedule(static) if(n > threaded_from)
      do i = 1, n
         ex(i) = ex(i) + (-self%mass(i))*x(2*n + i)
         ex(n + i) = ex(n + i) + self%mass(i)*x(2*n + i)
      end do
      !$omp end parallel do
   end subroutine apply_e

   subroutine operator_apply(self, x, y)
      class(newton_operator_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      call self%sys%apply(x, y)
   end subroutine operator_apply
end module twomem_newton_system
