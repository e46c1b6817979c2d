!> Square sparse matrices in compressed sparse row form, 1-based, columns sorted within each
!> row. The pattern is built once (P1 vertex adjacency, block systems) and values are refilled
!> in place, so solvers can keep pattern-dependent work (UMFPACK's symbolic analysis, ILU
!> patterns) between Newton steps.
module twomem_linalg_csr
   use twomem_base_kinds, only: dp, ip
   implicit none
   private

   public :: csr_t

   type :: csr_t
      integer(ip) :: n = 0
      integer(ip), allocatable :: row_ptr(:), col(:)
      real(dp), allocatable :: val(:)
   contains
      procedure :: init_pattern
      procedure :: nnz
      procedure :: find
      procedure :: matvec
      procedure :: diagonal
   end type csr_t

contains

   !> Take a pattern given row by row; columns are sorted here, values set to zero.
   subroutine init_pattern(self, row_ptr, col)
      class(csr_t), intent(inout) :: self
      integer(ip), intent(in) :: row_ptr(:), col(:)

      integer(ip) :: i

      self%n = int(size(row_ptr) - 1, ip)
      self%row_ptr = row_ptr
      self%col = col(1:row_ptr(size(row_ptr)) - 1)
      do i = 1, self%n
         call sort_ints(self%col(self%row_ptr(i):self%row_ptr(i + 1) - 1))
      end do
      if (allocated(self%val)) deallocate (self%val)
      allocate (self%val(size(self%col)))
      self%val = 0.0_dp
   end subroutine init_pattern

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

      !$omp parallel do default(none) shared(self, x, y) private(i, k, s) schedule(static)
      do i = 1, self%n
         s = 0.0_dp
         do k = self%row_ptr(i), self%row_ptr(i + 1) - 1
            s = s + self%val(k)*x(self%col(k))
         end do
         y(i) = s
      end do
      !$omp end parallel do
   end subroutine matvec

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

   !> Insertion sort: rows hold a handful of entries.
   pure subroutine sort_ints(a)
      integer(ip), intent(inout) :: a(:)

      integer(ip) :: i, j, key

      do i = 2, size(a)
         key = a(i)
         j = i - 1
         do while (j >= 1)
            if (a(j) <= key) exit
            a(j + 1) = a(j)
            j = j - 1
         end do
         a(j + 1) = key
      end do
   end subroutine sort_ints
end module twomem_linalg_csr
