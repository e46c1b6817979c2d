!> P1 finite-element assembly on one mesh: the stiffness matrix (unit coefficient), the lumped
!> mass |ω_a|/3 and the load vectors (f, ψ_a) by quadrature. Every vector and matrix row is
!> gathered by its own vertex from the triangles of its patch, in one parallel loop over
!> vertices: each thread writes only its own rows, so there are no atomics, no colouring and no
!> searches in a global pattern, and the result is the same for any thread count. A matrix
!> row is built in a small local list (a vertex has a handful of neighbours), sorted, and
!> written once; a first pass over the same loop counts the rows' lengths. On a rank's piece of
!> a distributed mesh only its own triangles are assembled: rows and vectors at vertices it
!> shares with other ranks hold its part only, which the caller sums across ranks.
module twomem_fem_assembly
   use twomem_base_kinds, only: dp, ip
   use twomem_base_sort, only: sort_pairs
   use twomem_mesh_triangulation, only: mesh_t, corner_of
   use twomem_linalg_csr, only: csr_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   implicit none
   private

   public :: p1_gradients, assemble_stiffness, stiffness_rows, lumped_mass, assemble_loads

contains

   !> Gradients of the three barycentric functions of triangle t, (2, 3).
   pure function p1_gradients(mesh, t) result(grad)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp) :: grad(2, 3)

      real(dp) :: p(2, 3), twice_area
      integer :: i, j, k

      ! vertex by vertex: a vector subscript of a component takes a heap temporary
      do i = 1, 3
         p(:, i) = mesh%vertices(:, mesh%triangles(i, t))
      end do
      twice_area = 2*mesh%area(t)
      do i = 1, 3
         j = modulo(i, 3) + 1
         k = modulo(i + 1, 3) + 1
         ! the opposite edge rotated by -90°, over twice the area (no array constructor: this
         ! runs millions of times, and a constructor may cost a heap temporary)
         grad(1, i) = (p(2, j) - p(2, k))/twice_area
         grad(2, i) = (p(1, k) - p(1, j))/twice_area
      end do
   end function p1_gradients

   !> K_ab = ∫ ∇ψ_a·∇ψ_b on all vertices (boundary rows included).
   subroutine assemble_stiffness(mesh, k)
      type(mesh_t), intent(in) :: mesh
      type(csr_t), intent(inout) :: k

      integer(ip) :: a
      real(dp), allocatable :: coupling(:)

      call stiffness_rows(mesh, [(a, a=1, mesh%nv)], k, coupling)
   end subroutine assemble_stiffness

   !> K restricted to the vertices with unknown(a) > 0, numbered by `unknown`, and for each of
   !> their rows coupling(i) = Σ K_ab over the neighbours b with unknown(b) = 0 (what a constant
   !> Dirichlet value on those vertices contributes to the right-hand side).
   subroutine stiffness_rows(mesh, unknown, k, coupling)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: unknown(:)
      type(csr_t), intent(inout) :: k
      real(dp), allocatable, intent(out) :: coupling(:)

      integer(ip), allocatable :: rows(:), row_ptr(:), col(:), cols(:), slot(:), order(:)
      real(dp), allocatable :: val(:), vals(:)
      integer(ip) :: n, i, a, width, r

      n = maxval(unknown)
      allocate (rows(n), row_ptr(n + 1), coupling(n))
      do a = 1, mesh%nv
         if (unknown(a) > 0) rows(unknown(a)) = a
      end do
      ! the rows in the order of their vertex's first patch triangle: consecutive rows then
      ! share their triangles' data in cache, where row order scatters them
      order = mesh%vertices_by_first_triangle()
      order = pack(unknown(order), unknown(order) > 0)
      ! a row has at most one column per patch triangle plus the diagonal
      width = maxval(mesh%patch_ptr(2:) - mesh%patch_ptr(:mesh%nv)) + 2
      row_ptr(1) = 1
      ! per-thread scratch: one row's columns and values, and where each unknown sits in the row
      ! being built (slot(c) = 0 once the row is done), which replaces a search per entry
      !$omp parallel default(none) shared(mesh, unknown, rows, row_ptr, n, width, order) private(i, r, cols, slot)
      allocate (cols(width), slot(n))
      slot = 0
      !$omp do schedule(static)
      do r = 1, n
         i = order(r)
         call count_row(mesh, unknown, rows(i), cols, slot, row_ptr(i + 1))
      end do
      !$omp end do
      deallocate (cols, slot)
      !$omp end parallel
      do i = 1, n
         row_ptr(i + 1) = row_ptr(i + 1) + row_ptr(i)
      end do
      allocate (col(row_ptr(n + 1) - 1), val(row_ptr(n + 1) - 1))
      !$omp parallel default(none) shared(mesh, unknown, rows, row_ptr, col, val, coupling, n, width, order) &
      !$omp private(i, r, cols, vals, slot)
      allocate (cols(width), vals(width), slot(n))
      slot = 0
      !$omp do schedule(static)
      do r = 1, n
         i = order(r)
         call gather_row(mesh, unknown, rows(i), cols, vals, slot, col(row_ptr(i):row_ptr(i + 1) - 1), &
                         val(row_ptr(i):row_ptr(i + 1) - 1), coupling(i))
      end do
      !$omp end do
      deallocate (cols, vals, slot)
      !$omp end parallel
      k%n = n
      k%ncol = n
      call move_alloc(row_ptr, k%row_ptr)
      call move_alloc(col, k%col)
      call move_alloc(val, k%val)
   end subroutine stiffness_rows

   !> Number of distinct unknowns among vertex a's neighbours (itself included); `cols` and
   !> `slot` are scratch (slot zero on entry and on return).
   pure subroutine count_row(mesh, unknown, a, cols, slot, count)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: unknown(:), a
      integer(ip), intent(inout) :: cols(:), slot(:)
      integer(ip), intent(out) :: count

      integer(ip) :: m, c
      integer :: j

      count = 0
      do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
         if (mesh%patch_triangles(m) > mesh%nt_owned) cycle
         do j = 1, 3
            c = unknown(mesh%triangles(j, mesh%patch_triangles(m)))
            if (c == 0) cycle
            if (slot(c) > 0) cycle
            count = count + 1
            cols(count) = c
            slot(c) = int(count, ip)
         end do
      end do
      slot(cols(1:count)) = 0
   end subroutine count_row

   !> Row of vertex a: columns sorted, values summed over the patch in patch order. In triangle
   !> t with a at corner i, K_ij = |t| ∇ψ_i·∇ψ_j = (e_i·e_j)/(4|t|), e_j the edge opposite corner j.
   !> cols, vals and slot are scratch for the row being built (slot as in count_row).
   pure subroutine gather_row(mesh, unknown, a, cols, vals, slot, col, val, coupling)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: unknown(:), a
      integer(ip), intent(inout) :: cols(:), slot(:)
      real(dp), intent(inout) :: vals(:)
      integer(ip), intent(out) :: col(:)
      real(dp), intent(out) :: val(:)
      real(dp), intent(out) :: coupling

      integer(ip) :: m, t, c, q
      real(dp) :: e(2, 3), entry, scale
      integer :: i, j, count

      count = 0
      coupling = 0.0_dp
      do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
         t = mesh%patch_triangles(m)
         if (t > mesh%nt_owned) cycle
         associate (corner => mesh%triangles(:, t))
            do j = 1, 3
               e(:, j) = mesh%vertices(:, corner(modulo(j + 1, 3) + 1)) - mesh%vertices(:, corner(modulo(j, 3) + 1))
            end do
         end associate
         scale = 1/(4*mesh%area(t))
         i = corner_of(mesh, t, a)
         do j = 1, 3
            entry = (e(1, i)*e(1, j) + e(2, i)*e(2, j))*scale
            c = unknown(mesh%triangles(j, t))
            if (c == 0) then
               coupling = coupling + entry
               cycle
            end if
            q = slot(c)
            if (q == 0) then
               count = count + 1
               cols(count) = c
               vals(count) = entry
               slot(c) = int(count, ip)
            else
               vals(q) = vals(q) + entry
            end if
         end do
      end do
      slot(cols(1:count)) = 0
      call sort_pairs(cols(1:count), vals(1:count))
      col = cols(1:count)
      val = vals(1:count)
   end subroutine gather_row

   !> |ω_a|/3: the weights of the lumped product ⟨w, v⟩_h.
   function lumped_mass(mesh) result(d)
      type(mesh_t), intent(in) :: mesh
      real(dp) :: d(mesh%nv)

      integer(ip) :: a, m

      !$omp parallel do default(none) shared(mesh, d) private(a, m) schedule(static)
      do a = 1, mesh%nv
         d(a) = 0.0_dp
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            if (mesh%patch_triangles(m) <= mesh%nt_owned) d(a) = d(a) + mesh%area(mesh%patch_triangles(m))
         end do
         d(a) = d(a)/3
      end do
      !$omp end parallel do
   end function lumped_mass

   !> f(:, α) = (f_α, ψ_a) for every vertex, both loads, by the degree-5 rule (data may jump
   !> inside elements; constant loads take the rule's sums once for all triangles).
   function assemble_loads(mesh, data) result(f)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp) :: f(mesh%nv, 2)

      type(quadrature_t) :: rule
      real(dp), allocatable :: local(:, :, :), bary(:, :), weights(:)
      real(dp) :: s1, s2, f_const(2), sums(3, 2)
      integer(ip) :: t, a, m
      integer :: q, i, alpha, nq
      logical :: constant

      rule = triangle_rule(5)
      ! the rule in plain arrays: the innermost loop should not chase descriptors
      nq = rule%n
      allocate (bary(3, nq), weights(nq))
      bary = rule%bary
      weights = rule%weights
      allocate (local(3, 2, mesh%nt))
      call data%constant_loads(f_const, constant)
      if (constant) then
         ! the rule's sums below do not depend on the triangle: formed once, in the same order
         ! (the same bits), instead of 14 load values and 42 products per triangle
         do i = 1, 3
            s1 = 0.0_dp
            s2 = 0.0_dp
            do q = 1, nq
               s1 = s1 + weights(q)*f_const(1)*bary(i, q)
               s2 = s2 + weights(q)*f_const(2)*bary(i, q)
            end do
            sums(i, :) = [s1, s2]
         end do
         !$omp parallel do default(none) shared(mesh, local, sums) private(t) schedule(static)
         do t = 1, mesh%nt_owned
            local(:, 1, t) = mesh%area(t)*sums(:, 1)
            local(:, 2, t) = mesh%area(t)*sums(:, 2)
         end do
         !$omp end parallel do
      else
         call quadrature_loads(mesh, data, bary, weights, local)
      end if
      !$omp parallel do default(none) shared(mesh, local, f) private(a, m, t, alpha) schedule(static)
      do a = 1, mesh%nv
         f(a, :) = 0.0_dp
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(m)
            if (t > mesh%nt_owned) cycle
            do alpha = 1, 2
               f(a, alpha) = f(a, alpha) + local(corner_of(mesh, t, a), alpha, t)
            end do
         end do
      end do
      !$omp end parallel do
   end function assemble_loads

   !> local(i, α, t) = (f_α, λ_i)_t by the rule (bary, weights) on every owned triangle.
   subroutine quadrature_loads(mesh, data, bary, weights, local)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp), intent(in) :: bary(:, :), weights(:)
      real(dp), intent(inout) :: local(:, :, :)

      real(dp), allocatable :: x(:, :), f_at(:, :)
      real(dp) :: p(2, 3), s1, s2
      integer(ip) :: t
      integer :: q, i, nq

      nq = size(weights)
      !$omp parallel default(none) shared(mesh, data, bary, weights, nq, local) private(t, q, i, x, f_at, p, s1, s2)
      allocate (x(2, nq), f_at(2, nq))
      !$omp do schedule(static)
      do t = 1, mesh%nt_owned
         do i = 1, 3
            p(:, i) = mesh%vertices(:, mesh%triangles(i, t))
         end do
         do q = 1, nq
            x(1, q) = bary(1, q)*p(1, 1) + bary(2, q)*p(1, 2) + bary(3, q)*p(1, 3)
            x(2, q) = bary(1, q)*p(2, 1) + bary(2, q)*p(2, 2) + bary(3, q)*p(2, 3)
         end do
         call data%loads_at(x, f_at)
         do i = 1, 3
            s1 = 0.0_dp
            s2 = 0.0_dp
            do q = 1, nq
               s1 = s1 + weights(q)*f_at(1, q)*bary(i, q)
               s2 = s2 + weights(q)*f_at(2, q)*bary(i, q)
            end do
            local(i, 1, t) = mesh%area(t)*s1
            local(i, 2, t) = mesh%area(t)*s2
         end do
      end do
      !$omp end do
      deallocate (x, f_at)
      !$omp end parallel
   end subroutine quadrature_loads
end module twomem_fem_assembly
