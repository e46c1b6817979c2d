!> Orders that follow the domain instead of a file's numbering. A mesher numbers triangles and
!> nodes in the order it made them, which above the cache's size scatters every patch, matrix
!> row and interpolation stencil over memory: a Gmsh mesh of 10^5 vertices solved in that order
!> took a quarter longer than the same mesh along a space-filling curve, every phase alike. The
!> curve is the Z-order (Morton) curve: a point's key interleaves the bits of its coordinates,
!> scaled to 15 bits each over a bounding square (a 2^15 × 2^15 grid, far finer than any mesh
!> this code solves), so consecutive keys are close in the plane. Sorting is deterministic, so
!> an order made twice is the same. A mesh of a few thousand triangles fits in the cache in any
!> order: it keeps its own (`worth_reordering`), and with it the paths of small cases.
module twomem_mesh_spatial_order
   use twomem_base_kinds, only: dp, ip
   implicit none
   private

   public :: z_order_key, renumber_along_curve, worth_reordering

   !> meshes of more triangles than this are worth numbering along the curve
   integer(ip), parameter :: reorder_above = 10000

contains

   !> Whether a mesh of nt triangles is worth numbering along the curve.
   pure logical function worth_reordering(nt)
      integer(ip), intent(in) :: nt

      worth_reordering = nt > reorder_above
   end function worth_reordering

   !> The Z-order key of point x in the square with lower-left corner `low` and side `width`.
   pure integer(ip) function z_order_key(x, low, width) result(key)
      real(dp), intent(in) :: x(2), low(2), width

      integer :: cells(2), bit

      cells = int(max(0.0_dp, min(32767.0_dp, (x - low)/width*32768)))
      key = 0
      do bit = 0, 14
         if (btest(cells(1), bit)) key = ibset(key, 2*bit)
         if (btest(cells(2), bit)) key = ibset(key, 2*bit + 1)
      end do
   end function z_order_key

   !> The triangles `list` (numbers into `triangles`, corners into `vertices`) in the order of
   !> their centroids along the Z-order curve over the bounding square of `vertices`.
   function triangles_along_curve(vertices, triangles, list) result(ordered)
      real(dp), intent(in) :: vertices(:, :)
      integer(ip), intent(in) :: triangles(:, :), list(:)
      integer(ip), allocatable :: ordered(:)

      integer(ip), allocatable :: keys(:)
      real(dp) :: low(2), width, c(2)
      integer(ip) :: k

      if (size(list) == 0) then
         allocate (ordered(0))
         return
      end if
      low = minval(vertices, dim=2)
      width = max(maxval(vertices(1, :)) - low(1), maxval(vertices(2, :)) - low(2), tiny(1.0_dp))
      allocate (keys(size(list)))
      !$omp parallel do default(none) shared(vertices, triangles, list, keys, low, width) private(k, c) &
      !$omp schedule(static)
      do k = 1, size(list, kind=ip)
         associate (t => list(k))
            c = (vertices(:, triangles(1, t)) + vertices(:, triangles(2, t)) + vertices(:, triangles(3, t)))/3
         end associate
         keys(k) = z_order_key(c, low, width)
      end do
      !$omp end parallel do
      ordered = list(radix_order(keys))
   end function triangles_along_curve

   !> A whole mesh numbered along the curve, in place: the triangles by their centroids and the
   !> vertices as these triangles first meet them (any vertex of no triangle last).
   !> triangle_order(k) and vertex_order(k) are the old numbers of triangle and vertex k.
   subroutine renumber_along_curve(vertices, triangles, vertex_order, triangle_order)
      real(dp), intent(inout) :: vertices(:, :)
      integer(ip), intent(inout) :: triangles(:, :)
      integer(ip), allocatable, intent(out) :: vertex_order(:), triangle_order(:)

      integer(ip), allocatable :: new_number(:), renumbered(:, :)
      integer(ip) :: k, a, n
      integer :: m

      triangle_order = triangles_along_curve(vertices, triangles, [(k, k=1, size(triangles, 2, kind=ip))])
      allocate (new_number(size(vertices, 2)), vertex_order(size(vertices, 2)), renumbered(3, size(triangles, 2)))
      new_number = 0
      n = 0
      do k = 1, size(triangles, 2, kind=ip)
         do m = 1, 3
            a = triangles(m, triangle_order(k))
            if (new_number(a) == 0) then
               n = n + 1
               new_number(a) = n
               vertex_order(n) = a
            end if
            renumbered(m, k) = new_number(a)
         end do
      end do
      do a = 1, size(vertices, 2, kind=ip)
         if (new_number(a) /= 0) cycle
         n = n + 1
         vertex_order(n) = a
      end do
      triangles = renumbered
      vertices = vertices(:, vertex_order)
   end subroutine renumber_along_curve

   !> The stable permutation that sorts keys in [0, 2^30) ascending: three passes of a counting
   !> sort on 10 bits each, O(n), where a comparison sort of 2·10^6 keys took a second. The keys
   !> move with the permutation, so that every pass reads them in sequence.
   function radix_order(keys) result(order)
      integer(ip), intent(in) :: keys(:)
      integer(ip), allocatable :: order(:)

      integer(ip), allocatable :: next(:), sorted(:), next_keys(:), starts(:)
      integer(ip) :: i, digit
      integer :: pass

      allocate (order(size(keys)), next(size(keys)), next_keys(size(keys)), starts(0:1024))
      order = [(i, i=1, size(keys, kind=ip))]
      sorted = keys
      do pass = 0, 2
         starts = 0
         do i = 1, size(keys, kind=ip)
            digit = ibits(sorted(i), 10*pass, 10)
            starts(digit + 1) = starts(digit + 1) + 1
         end do
         ! starts(d): where digit d's run starts, less one
         do i = 1, 1024
            starts(i) = starts(i) + starts(i - 1)
         end do
         do i = 1, size(keys, kind=ip)
            digit = ibits(sorted(i), 10*pass, 10)
            starts(digit) = starts(digit) + 1
            next(starts(digit)) = order(i)
            next_keys(starts(digit)) = sorted(i)
         end do
         call move_alloc(next, order)
         call move_alloc(next_keys, sorted)
         if (pass < 2) allocate (next(size(keys)), next_keys(size(keys)))
      end do
   end function radix_order
end module twomem_mesh_spatial_order
