!> P1 finite-element assembly on one mesh: the stiffness matrix (unit coefficient), the lumped
!> mass |ω_a|/3 and load vectors (f, ψ_a) by quadrature. Element contributions are computed in a
!> parallel loop over triangles into per-element arrays, then gathered in a parallel loop over
!> vertices, each thread writing only its own rows: no atomics, no colouring, same result for
!> any thread count.
module twomem_fem_assembly
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_linalg_csr, only: csr_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   implicit none
   private

   public :: p1_gradients, assemble_stiffness, lumped_mass, assemble_load

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

   !> K_ab = ∫ ∇ψ_a·∇ψ_b on all vertices (boundary rows included; the caller restricts).
   subroutine assemble_stiffness(mesh, k)
      type(mesh_t), intent(in) :: mesh
      type(csr_t), intent(inout) :: k

      real(dp), allocatable :: local(:, :, :)
      real(dp) :: grad(2, 3)
      integer(ip) :: t, a, m, i, j, pos
      integer(ip), allocatable :: row_ptr(:), col(:)

      call p1_pattern(mesh, row_ptr, col)
      call k%init_pattern(row_ptr, col)
      allocate (local(3, 3, mesh%nt))
      !$omp parallel do default(none) shared(mesh, local) private(t, grad) schedule(static)
      do t = 1, mesh%nt
         grad = p1_gradients(mesh, t)
         local(:, :, t) = mesh%area(t)*matmul(transpose(grad), grad)
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(mesh, local, k) private(a, m, t, i, j, pos) schedule(static)
      do a = 1, mesh%nv
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(m)
            i = local_index(mesh, t, a)
            do j = 1, 3
               pos = k%find(a, mesh%triangles(j, t))
               k%val(pos) = k%val(pos) + local(i, j, t)
            end do
         end do
      end do
      !$omp end parallel do
   end subroutine assemble_stiffness

   !> |ω_a|/3: the weights of the lumped product ⟨w, v⟩_h.
   function lumped_mass(mesh) result(d)
      type(mesh_t), intent(in) :: mesh
      real(dp) :: d(mesh%nv)

      integer(ip) :: a

      do a = 1, mesh%nv
         d(a) = sum(mesh%area(mesh%patch_triangles(mesh%patch_ptr(a):mesh%patch_ptr(a + 1) - 1)))/3
      end do
   end function lumped_mass

   !> (f_alpha, ψ_a) for every vertex, by the degree-5 rule (data may jump inside elements).
   function assemble_load(mesh, data, alpha) result(f)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      integer, intent(in) :: alpha
      real(dp) :: f(mesh%nv)

      type(quadrature_t) :: rule
      real(dp), allocatable :: local(:, :)
      real(dp) :: x(2), fx
      integer(ip) :: t, a, m
      integer :: q

      rule = triangle_rule(5)
      allocate (local(3, mesh%nt))
      !$omp parallel do default(none) shared(mesh, data, alpha, rule, local) private(t, q, x, fx) &
      !$omp schedule(static)
      do t = 1, mesh%nt
         local(:, t) = 0.0_dp
         do q = 1, rule%n
            x = matmul(mesh%vertices(:, mesh%triangles(:, t)), rule%bary(:, q))
            fx = data%load(alpha, x)
            local(:, t) = local(:, t) + rule%weights(q)*fx*rule%bary(:, q)
         end do
         local(:, t) = mesh%area(t)*local(:, t)
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(mesh, local, f) private(a, m, t) schedule(static)
      do a = 1, mesh%nv
         f(a) = 0.0_dp
         do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(m)
            f(a) = f(a) + local(local_index(mesh, t, a), t)
         end do
      end do
      !$omp end parallel do
   end function assemble_load

   pure integer(ip) function local_index(mesh, t, a) result(i)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t, a

      do i = 1, 3
         if (mesh%triangles(i, t) == a) return
      end do
      i = 0
   end function local_index

   !> Vertex adjacency (a vertex, its edge neighbours) as a CSR pattern.
   subroutine p1_pattern(mesh, row_ptr, col)
      type(mesh_t), intent(in) :: mesh
      integer(ip), allocatable, intent(out) :: row_ptr(:), col(:)

      integer(ip) :: a, e
      integer(ip), allocatable :: fill(:)

      allocate (row_ptr(mesh%nv + 1))
      row_ptr = 1
      do e = 1, mesh%ne
         row_ptr(mesh%edges(:, e) + 1) = row_ptr(mesh%edges(:, e) + 1) + 1
      end do
      row_ptr(1) = 1
      do a = 1, mesh%nv
         row_ptr(a + 1) = row_ptr(a + 1) + row_ptr(a)
      end do
      allocate (col(row_ptr(mesh%nv + 1) - 1))
      allocate (fill(mesh%nv))
      fill = row_ptr(1:mesh%nv)
      do a = 1, mesh%nv
         col(fill(a)) = a
         fill(a) = fill(a) + 1
      end do
      do e = 1, mesh%ne
         associate (ab => mesh%edges(:, e))
            col(fill(ab(1))) = ab(2)
            fill(ab(1)) = fill(ab(1)) + 1
            col(fill(ab(2))) = ab(1)
            fill(ab(2)) = fill(ab(2)) + 1
         end associate
      end do
   end subroutine p1_pattern
end module twomem_fem_assembly
