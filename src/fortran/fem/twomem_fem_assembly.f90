!> P1 finite-element assembly on one mesh: the stiffness matrix (unit coefficient), the lumped
!> mass |ω_a|/3 and the load vectors (f, ψ_a) by quadrature. Every vector and matrix row is
!> gathered by its own vertex from the triangles of its patch, in one parallel loop over
!> vertices: each thread writes only its own rows, so there are no atomics, no colouring and no
!> searches in a global pattern, and the result is the same for any thread count. A matrix
!> row is built in a small local list (a vertex has a handful of neighbours), sorted, and
!> written once; a first pass over the same loop counts the rows' lengths.
module twomem_fem_assembly
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
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

      real(dp) :: p(2, 3)
      integer :: i, j, k

      p = mesh%vertices(:, mesh%triangles(:, t))
      do i = 1, 3
         j = modulo(i, 3) + 1
         k = modulo(i + 1, 3) + 1
         ! the opposite edge rotated by -90°, over twice the area
         grad(:, i) = [p(2, j) - p(2, k), p(1, k) - p(1, j)]/(2*mesh%area(t))
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

      integer(ip), allocatable :: rows(:), row_ptr(:), col(:)
      real(dp), allocatable :: val(:)
      integer(ip) :: n, i, a, width

      n = maxval(unknown)
      allocate (rows(n), row_ptr(n + 1), coupling(n))
      do a = 1, mesh%nv
         if (unknown(a) > 0) rows(unknown(a)) = a
      end do
      ! a row has at most one column per patch triangle plus the diagonal
      width = maxval(mesh%patch_ptr(2:) - mesh%patch_ptr(:mesh%nv)) + 2
      row_ptr(1) = 1
      !$omp parallel do default(none) shared(mesh, unknown, rows, row_ptr, n, width) private(i) schedule(static)
      do i = 1, n
         row_ptr(i + 1) = row_length(mesh, unknown, rows(i), width)
      end do
      !$omp end parallel do
      do i = 1, n
         row_ptr(i + 1) = row_ptr(i + 1) + row_ptr(i)
      end do
      allocate (col(row_ptr(n + 1) - 1), val(row_ptr(n + 1) - 1))
      !$omp parallel do default(none) shared(mesh, unknown, rows, row_ptr, col, val, coupling, n, width) private(i) &
      !$omp schedule(static)
      do i = 1, n
         call gather_row(mesh, unknown, rows(i), width, col(row_ptr(i):row_ptr(i + 1) - 1), &
                         val(row_ptr(i):row_ptr(i + 1) - 1), coupling(i))
      end do
      !$omp end parallel do
      k%n = n
      k%ncol = n
      call move_alloc(row_ptr, k%row_ptr)
      call move_alloc(col, k%col)
      call move_alloc(val, k%val)
   end subroutine stiffness_rows

   !> Number of distinct unknowns among vertex a's neighbours (itself included).
   pure integer(ip) function row_length(mesh, unknown, a, width) result(count)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: unknown(:), a, width

      integer(ip) :: cols(width), m, c
      integer :: j

      count = 0
      do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
         do j = 1, 3
            c = unknown(mesh%triangles(j, mesh%patch_triangles(m)))
            if (c == 0) cycle
            if (any(cols(1:count) == c)) cycle
            count = count + 1
            cols(count) = c
         end do
      end do
   end function row_length

   !> Row of vertex a: columns sorted, values summed over the patch in patch order.
   pure subroutine gather_row(mesh, unknown, a, width, col, val, coupling)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: unknown(:), a, width
      integer(ip), intent(out) :: col(:)
      real(dp), intent(out) :: val(:)
      real(dp), intent(out) :: coupling

      integer(ip) :: cols(width), m, t, c, key
      real(dp) :: vals(width), grad(2, 3), entry, v
      integer :: i, j, count, q, p

      count = 0
      coupling = 0.0_dp
      do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
         t = mesh%patch_triangles(m)
         grad = p1_gradients(mesh, t)
         i = findloc(mesh%triangles(:, t), a, dim=1)
         do j = 1, 3
            entry = mesh%area(t)*(grad(1, i)*grad(1, j) + grad(2, i)*grad(2, j))
            c = unknown(mesh%triangles(j, t))
            if (c == 0) then
               coupling = coupling + entry
               cycle
            end if
            q = findloc(cols(1:count), c, dim=1)
            if (q == 0) then
               count = count + 1
               cols(count) = c
               vals(count) = entry
            else
               vals(q) = vals(q) + entry
            end if
         end do
      end do
      ! insertion sort by column (a handful of entries)
      do q = 2, count
         key = cols(q)
         v = vals(q)
         p = q - 1
         do while (p >= 1)
            if (cols(p) <= key) exit
            cols(p + 1) = cols(p)
            vals(p + 1) = vals(p)
            p = p - 1
         end do
         cols(p + 1) = key
         vals(p + 1) = v
      end do
      col = cols(1:count)
      val = vals(1:count)
   end subroutine gather_row

   !> |ω_a|/3: the weights of the lumped product ⟨w, v⟩_h.
   function lumped_mass(mesh) result(d)
      type(mesh_t), intent(in) :: mesh
      real(dp) :: d(mesh%nv)

      integer(ip) :: a

      !$omp parallel do default(none) shared(mesh, d) private(a) schedule(static)
      do a = 1, mesh%nv
         d(a) = sum(mesh%area(mesh%patch_triangles(mesh%patch_ptr(a):mesh%patch_ptr(a + 1) - 1)))/3
      end do
      !$omp end parallel do
   end function lumped_mass

   !> f(:, α) = (f_α, ψ_a) for every vertex, both loads, by the degree-5 rule (data may jump
   !> inside elements).
   function assemble_loads(mesh, data) result(f)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp) :: f(mesh%nv, 2)

      type(quadrature_t) :: rule
      real(dp), allocatable :: local(:, :, :)
      real(dp) :: x(2), wf(2), p(2, 3)
      integer(ip) :: t, a, m
      integer :: q, i, alpha

      rule = triangle_rule(5)
      allocate (local(3, 2, mesh%nt))
      !$omp parallel do default(none) shared(mesh, data, rule, local) private(t, q, i, x, wf, p) schedule(static)
      do t = 1, mesh%nt
         p = mesh%vertices(:, mesh%triangles(:, t))
         local(:, :, t) = 0.0_dp
         do q = 1, rule%n
            x = rule%bary(1, q)*p(:, 1) + rule%bary(2, q)*p(:, 2) + rule%bary(3, q)*p(:, 3)
            wf = rule%weights(q)*[data%load(1, x), data%load(2, x)]
            do i = 1, 3
               local(i, :, t) = local(i, :, t) + wf*rule%bary(i, q)
            end do
         end do
         local(:, :, t) = mesh%area(t)*local(:, :, t)
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(mesh, local, f) private(a, m, t, alpha) schedule(static)
      do a = 1, mesh%nv
         f(a, :) = 0.0_dp
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(m)
            do alpha = 1, 2
               f(a, alpha) = f(a, alpha) + local(findloc(mesh%triangles(:, t), a, dim=1), alpha, t)
            end do
         end do
      end do
      !$omp end parallel do
   end function assemble_loads
end module twomem_fem_assembly
