!> The energy error |||u − u_h|||_K = (Σ_α μ_α ‖∇(u_α − u_αh)‖²_K)^{1/2} per element, against a
!> known exact solution, by a 16-point degree-8 rule: the exact gradients have a kink inside the
!> elements crossed by the free boundary, and a rich rule keeps the measured error honest there.
module twomem_fem_error
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_fem_assembly, only: p1_gradients
   implicit none
   private

   public :: energy_error_per_element

contains

   !> Per-element energy error of nodal fields u1, u2 (whole mesh, boundary values included).
   function energy_error_per_element(mesh, data, u1, u2) result(err_k)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp), intent(in) :: u1(:), u2(:)
      real(dp) :: err_k(mesh%nt)

      type(quadrature_t) :: rule
      real(dp) :: grad(2, 3), gh(2, 2), x(2), u(3), gx(2, 2), s
      integer(ip) :: t
      integer :: q

      rule = triangle_rule(8)
      !$omp parallel do default(none) shared(mesh, data, u1, u2, rule, err_k) &
      !$omp private(t, q, grad, gh, x, u, gx, s) schedule(static)
      do t = 1, mesh%nt
         grad = p1_gradients(mesh, t)
         gh(:, 1) = matmul(grad, u1(mesh%triangles(:, t)))
         gh(:, 2) = matmul(grad, u2(mesh%triangles(:, t)))
         s = 0.0_dp
         do q = 1, rule%n
            x = matmul(mesh%vertices(:, mesh%triangles(:, t)), rule%bary(:, q))
            call data%exact(x, u, gx)
            s = s + rule%weights(q)*(data%mu1*sum((gx(:, 1) - gh(:, 1))**2) + &
                                     data%mu2*sum((gx(:, 2) - gh(:, 2))**2))
         end do
         err_k(t) = sqrt(mesh%area(t)*s)
      end do
      !$omp end parallel do
   end function energy_error_per_element
end module twomem_fem_error
