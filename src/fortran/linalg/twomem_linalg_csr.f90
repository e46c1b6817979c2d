!> Sparse matrices in compressed sparse row form, 1-based, columns sorted within each row:
!> square system matrices, and the rectangular prolongations of multigrid (`ncol` columns). The
!> pattern is built once (P1 vertex adjacency, block systems) and values are refilled in place,
!> so solvers can keep pattern-dependent work (UMFPACK's symbolic analysis, ILU patterns,
!> Galerkin product patterns) between Newton steps.
module twomem_linalg_csr
   use twomem_base_kinds, only: dp, ip
   use twomem_base_sort, only: sort_row
   use twomem_linalg_vectors, only: copy_allocated, threaded_from
   implicit none
   private

   public :: csr_t, cut_entry

   type :: csr_t
      !> rows and columns (ncol = n unless the pattern was given a column count)
      integer(ip) :: n = 0, ncol = 0
      integer(ip), allocatable :: row_ptr(:), col(:)
      real(dp), allocatable :: val(:)
   contains
      procedure :: init_pattern
      procedure :: copy_from
      procedure :: nnz
      procedure :: find
      procedure :: matvec
      procedure :: cut_matvec
      procedure :: residual
      procedure :: subtract_product
      procedure :: diagonal
      procedure :: transposed
      procedure :: free => csr_free
   end type csr_t

contains

   !> Take a pattern given row by row; columns are sorted here, values set to zero. `ncol`
   !> defaults to the number of rows (a square matrix).
   subroutine init_pattern(self, row_ptr, col, ncol)
      class(csr_t), intent(inout) :: self
      integer(ip), intent(in) :: row_ptr(:), col(:)
      integer(ip), intent(in), optional :: ncol

      integer(ip) :: i

      self%n = int(size(row_ptr) - 1, ip)
      self%ncol = self%n
      if (present(ncol)) self%ncol = ncol
      self%row_ptr = row_ptr
      self%col = col(1:row_ptr(size(row_ptr)) - 1)
      if (allocated(self%val)) deallocate (self%val)
      allocate (self%val(size(self%col)))
      ! rows are short and mostly given sorted: an insertion sort per row, rows in parallel (the
      ! Newton pattern has 3n of them)
      !$omp parallel do default(none) shared(self) private(i) schedule(static) if(self%n > threaded_from)
      do i = 1, self%n
         call sort_row(self%col(self%row_ptr(i):self%row_ptr(i + 1) - 1))
         self%val(self%row_ptr(i):self%row_ptr(i + 1) - 1) = 0.0_dp
      end do
      !$omp end parallel do
   end subroutine init_pattern

   !> self becomes a copy of source, its arrays written by the threads (`copy_allocated`): a
   !> plain assignment would leave the first touch of every fresh page to one core.
   subroutine copy_from(self, source)
      class(csr_t), intent(inout) :: self
      type(csr_t), intent(in) :: source

      call self%free()
      self%n = source%n
      self%ncol = source%ncol
      if (allocated(source%row_ptr)) call copy_allocated(source%row_ptr, self%row_ptr)
      if (allocated(source%col)) call copy_allocated(source%col, self%col)
      if (allocated(source%val)) call copy_allocated(source%val, self%val)
   end subroutine copy_from

   !> The matrix goes: no rows, no entries.
   subroutine csr_free(self)
      class(csr_t), intent(inout) :: self

      if (allocated(self%row_ptr)) deallocate (self%row_ptr)
      if (allocated(self%col)) deallocate (self%col)
      if (allocated(self%val)) deallocate (self%val)
      self%n = 0
      self%ncol = 0
   end subroutine csr_free

   pure integer(ip) function nnz(self)
      class(csr_t), intent(in) :: self

      nnz = self%row_ptr(self%n + 1) - 1
   end function nnz

   !> Position of entry (i, j) in `val`, 0 if it is not in the pattern (binary search).
   pure integer(ip) function find(self, i, j) result(pos)
      class(csr_t), intent(in) :: self
      integer(ip), intent(in) :: i, j

      integer(ip) :: lo, hi, mid

      lo = self%row_ptr(i)
      hi = self%row_ptr(i + 1) - 1
      pos = 0
      do while (lo <= hi)
         mid = (lo + hi)/2
         if (self%col(mid) == j) then
            pos = mid
            return
         else if (self%col(mid) < j) then
            lo = mid + 1
         else
            hi = mid - 1
         end if
      end do
   end function find

   !> y = A x
   subroutine matvec(self, x, y)
      class(csr_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      integer(ip) :: i, k
      real(dp) :: s

      !$omp parallel do default(none) shared(self, x, y) private(i, k, s) schedule(static) if(self%n > threaded_from)
      do i = 1, self%n
         s = 0.0_dp
         do k = self%row_ptr(i), self%row_ptr(i + 1) - 1
            s = s + self%val(k)*x(self%col(k))
         end do
         y(i) = s
      end do
      !$omp end parallel do
   end subroutine matvec

   !> y = A_cut x, A_cut being A with the rows and columns of the `fixed` unknowns zeroed and its
   !> diagonal replaced by `diagonal` (`cut_entry`): an operator that differs from a stored one
   !> only there (the Newton w-block: the stiffness with the contact unknowns cut out and a
   !> diagonal shift) applied without storing its matrix. x must vanish at the fixed unknowns
   !> (as every vector of a V-cycle on A_cut does), so a cut column adds A's value times 0
   !> where the stored matrix adds 0 times 0, and no mask is read per entry. A's diagonal must be
   !> in its pattern and the columns sorted: the row is then summed in the stored matrix's order
   !> with the same products, so y has its bits.
   subroutine cut_matvec(self, diagonal, fixed, x, y)
      class(csr_t), intent(in) :: self
      real(dp), intent(in) :: diagonal(:)
      logical, intent(in) :: fixed(:)
      real(dp), intent(in) :: x(:)
      real(dp), intent(out) :: y(:)

      integer(ip) :: i, k
      real(dp) :: s

      !$omp parallel do default(none) shared(self, diagonal, fixed, x, y) private(i, k, s) schedule(static) &
      !$omp if(self%n > threaded_from)
      do i = 1, self%n
         if (fixed(i)) then
            ! an identity row (or a zero one, in a part of a shared row)
            y(i) = diagonal(i)*x(i)
            cycle
         end if
         s = 0.0_dp
         k = self%row_ptr(i)
         do while (self%col(k) < i)
            s = s + self%val(k)*x(self%col(k))
            k = k + 1
         end do
         s = s + diagonal(i)*x(i)
         do k = k + 1, self%row_ptr(i + 1) - 1
            s = s + self%val(k)*x(self%col(k))
         end do
         y(i) = s
      end do
      !$omp end parallel do
   end subroutine cut_matvec

   !> Entry k (of row i) of A_cut (`cut_matvec`): diagonal(i) on the diagonal, 0 in the row or
   !> column of a fixed unknown, A's value elsewhere.
   pure real(dp) function cut_entry(a, diagonal, fixed, i, k) result(v)
      type(csr_t), intent(in) :: a
      real(dp), intent(in) :: diagonal(:)
      logical, intent(in) :: fixed(:)
      integer(ip), intent(in) :: i, k

      v = merge(0.0_dp, a%val(k), fixed(i) .or. fixed(a%col(k)))
      v = merge(diagonal(i), v, a%col(k) == i)
   end function cut_entry

   !> r = b − A x
   subroutine residual(self, b, x, r)
      class(csr_t), intent(in) :: self
      real(dp), intent(in) :: b(:), x(:)
      real(dp), intent(out) :: r(:)

      integer(ip) :: i, k
      real(dp) :: s

      !$omp parallel do default(none) shared(self, b, x, r) private(i, k, s) schedule(static) if(self%n > threaded_from)
      do i = 1, self%n
         s = b(i)
         do k = self%row_ptr(i), self%row_ptr(i + 1) - 1
            s = s - self%val(k)*x(self%col(k))
         end do
         r(i) = s
      end do
      !$omp end parallel do
   end subroutine residual

   !> y = y − A x
   subroutine subtract_product(self, x, y)
      class(csr_t), intent(in) :: self
      real(dp), intent(in) :: x(:)
      real(dp), intent(inout) :: y(:)

      integer(ip) :: i, k
      real(dp) :: s

      !$omp parallel do default(none) shared(self, x, y) private(i, k, s) schedule(static) if(self%n > threaded_from)
      do i = 1, self%n
         s = y(i)
         do k = self%row_ptr(i), self%row_ptr(i + 1) - 1
            s = s - self%val(k)*x(self%col(k))
         end do
         y(i) = s
      end do
      !$omp end parallel do
   end subroutine subtract_product

   function diagonal(self) result(d)
      class(csr_t), intent(in) :: self
      real(dp) :: d(self%n)

      integer(ip) :: i, k

      d = 0.0_dp
      do i = 1, self%n
         k = self%find(i, i)
         if (k > 0) d(i) = self%val(k)
      end do
   end function diagonal

   !> Aᵀ with sorted columns (a counting sort by column, so rows come out in order).
   function transposed(self) result(t)
      class(csr_t), intent(in) :: self
      type(csr_t) :: t

      integer(ip) :: i, k, j
      integer(ip), allocatable :: fill(:)

      t%n = self%ncol
      t%ncol = self%n
      allocate (t%row_ptr(t%n + 1), t%col(self%nnz()), t%val(self%nnz()))
      t%row_ptr = 0
      do k = 1, self%nnz()
         t%row_ptr(self%col(k) + 1) = t%row_ptr(self%col(k) + 1) + 1
      end do
      t%row_ptr(1) = 1
      do i = 1, t%n
         t%row_ptr(i + 1) = t%row_ptr(i + 1) + t%row_ptr(i)
      end do
      fill = t%row_ptr(1:t%n)
      do i = 1, self%n
         do k = self%row_ptr(i), self%row_ptr(i + 1) - 1
            j = self%col(k)
            t%col(fill(j)) = i
            t%val(fill(j)) = self%val(k)
            fill(j) = fill(j) + 1
         end do
      end do
   end function transposed
end module twomem_linalg_csr
