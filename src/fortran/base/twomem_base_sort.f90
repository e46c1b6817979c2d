!> Sorting of integer keys, for the bookkeeping of distributed runs (interfaces listed in
!> whole-mesh order, keys numbered on rank 0). Heap sort: O(n log n) in the worst case, no
!> recursion, no extra memory. And insertion sorts of a sparse row's handful of columns, with
!> or without their values, where a heap sort's set-up would cost more than the sorting.
module twomem_base_sort
   use twomem_base_kinds, only: dp, ip
   implicit none
   private

   public :: sort_ints, sorting_permutation, sort_pairs, sort_row

   !> Insertion sort of `key` (a row's handful of columns), applying the same moves to `other`:
   !> the row's values, or where its entries come from.
   interface sort_pairs
      module procedure sort_pairs_values, sort_pairs_positions
   end interface sort_pairs

contains

   !> a in ascending order.
   pure subroutine sort_ints(a)
      integer(ip), intent(inout) :: a(:)

      integer(ip), allocatable :: none(:)

      allocate (none(size(a)))
      call heap_sort(a, none)
   end subroutine sort_ints

   !> The permutation that puts `keys` in ascending order: keys(order) is sorted.
   pure function sorting_permutation(keys) result(order)
      integer(ip), intent(in) :: keys(:)
      integer(ip), allocatable :: order(:)

      integer(ip), allocatable :: k(:)
      integer(ip) :: i

      ! allocated first: gfortran 12 warns about assigning to an unallocated array at -O0
      allocate (k(size(keys)), order(size(keys)))
      k(:) = keys
      order(:) = [(i, i=1, size(keys, kind=ip))]
      call heap_sort(k, order)
   end function sorting_permutation

   !> Sort `key` ascending, applying the same moves to `other`.
   pure subroutine heap_sort(key, other)
      integer(ip), intent(inout) :: key(:), other(:)

      integer(ip) :: n, i

      n = size(key, kind=ip)
      do i = n/2, 1, -1
         call sift(key, other, i, n)
      end do
      do i = n, 2, -1
         call swap(key, other, 1_ip, i)
         call sift(key, other, 1_ip, i - 1)
      end do
   end subroutine heap_sort

   pure subroutine sift(key, other, start, last)
      integer(ip), intent(inout) :: key(:), other(:)
      integer(ip), intent(in) :: start, last

      integer(ip) :: root, child

      root = start
      do while (2*root <= last)
         child = 2*root
         if (child < last) then
            if (key(child + 1) > key(child)) child = child + 1
         end if
         if (key(root) >= key(child)) return
         call swap(key, other, root, child)
         root = child
      end do
   end subroutine sift

   pure subroutine swap(key, other, i, j)
      integer(ip), intent(inout) :: key(:), other(:)
      integer(ip), intent(in) :: i, j

      integer(ip) :: t

      t = key(i)
      key(i) = key(j)
      key(j) = t
      t = other(i)
      other(i) = other(j)
      other(j) = t
   end subroutine swap

   pure subroutine sort_pairs_values(key, other)
      integer(ip), intent(inout) :: key(:)
      real(dp), intent(inout) :: other(:)

      integer(ip) :: positions(size(key)), i

      positions = [(i, i=1, size(key, kind=ip))]
      call sort_pairs_positions(key, positions)
      other = other(positions)
   end subroutine sort_pairs_values

   pure subroutine sort_pairs_positions(key, other)
      integer(ip), intent(inout) :: key(:)
      integer(ip), intent(inout) :: other(:)

      integer(ip) :: i, j, k
      integer(ip) :: o

      do i = 2, size(key)
         k = key(i)
         o = other(i)
         j = i - 1
         do while (j >= 1)
            if (key(j) <= k) exit
            key(j + 1) = key(j)
            other(j + 1) = other(j)
            j = j - 1
         end do
         key(j + 1) = k
         other(j + 1) = o
      end do
   end subroutine sort_pairs_positions

   !> Insertion sort of `key` (a row's handful of columns).
   pure subroutine sort_row(key)
      integer(ip), intent(inout) :: key(:)

      integer(ip) :: i, j, k

      do i = 2, size(key)
         k = key(i)
         j = i - 1
         do while (j >= 1)
            if (key(j) <= k) exit
            key(j + 1) = key(j)
            j = j - 1
         end do
         key(j + 1) = k
      end do
   end subroutine sort_row
end module twomem_base_sort
