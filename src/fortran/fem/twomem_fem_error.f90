!> The energy error |||u − u_h|||_K = (Σ_α μ_α ‖∇(u_α − u_αh)‖²_K)^{1/2} per element, against a
!> known exact solution. The exact gradients have a kink on the free boundary (and wherever
!> the data jump), which no fixed rule integrates well on the elements it crosses; so each
!> element is integrated with the 16-point degree-8 rule and, where that disagrees with the
!> 7-point degree-5 rule, split into its four red children, recursively (at most `max_depth`
!> times). On smooth elements the two rules agree to round-off and one comparison suffices.
module twomem_fem_error
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_fem_assembly, only: p1_gradients
   implicit none
   private

   public :: energy_error_per_element

   integer, parameter :: max_depth = 5
   !> relative agreement at which an element's integral is accepted
   real(dp), parameter :: accept_rtol = 1.0e-8_dp

contains

   !> Per-element energy error of nodal fields u1, u2 (whole mesh, boundary values included).
   function energy_error_per_element(mesh, data, u1, u2) result(err_k)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp), intent(in) :: u1(:), u2(:)
      real(dp) :: err_k(mesh%nt)

      type(quadrature_t) :: rule, check
      real(dp) :: grad(2, 3), gh(2, 2)
      integer(ip) :: t

      rule = triangle_rule(8)
      check = triangle_rule(5)
      !$omp parallel do default(none) shared(mesh, data, u1, u2, rule, check, err_k) &
      !$omp private(t, grad, gh) schedule(dynamic, 64)
      do t = 1, mesh%nt
         grad = p1_gradients(mesh, t)
         gh(:, 1) = matmul(grad, u1(mesh%triangles(:, t)))
         gh(:, 2) = matmul(grad, u2(mesh%triangles(:, t)))
         err_k(t) = sqrt(max(0.0_dp, adaptive_integral(data, rule, check, gh, &
                                                       mesh%vertices(:, mesh%triangles(:, t)), &
                                                       mesh%area(t), 0)))
      end do
      !$omp end parallel do
   end function energy_error_per_element

   !> ∫_T Σ_α μ_α |∇u_α − g_α|² by the rule on T.
   real(dp) function rule_integral(data, rule, gh, p, area) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: gh(2, 2), p(2, 3), area

      real(dp) :: x(2), u(3), gx(2, 2)
      integer :: q

      s = 0.0_dp
      do q = 1, rule%n
         x = matmul(p, rule%bary(:, q))
         call data%exact(x, u, gx)
         s = s + rule%weights(q)*(data%mu1*sum((gx(:, 1) - gh(:, 1))**2) + &
                                  data%mu2*sum((gx(:, 2) - gh(:, 2))**2))
      end do
      s = area*s
   end function rule_integral

   !> The rule on T where it agrees with the check rule, else the sum over T's four children.
   recursive real(dp) function adaptive_integral(data, rule, check, gh, p, area, depth) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule, check
      real(dp), intent(in) :: gh(2, 2), p(2, 3), area
      integer, intent(in) :: depth

      real(dp) :: child(2, 3, 4)
      integer :: k

      s = rule_integral(data, rule, gh, p, area)
      if (depth >= max_depth) return
      if (abs(s - rule_integral(data, check, gh, p, area)) <= accept_rtol*abs(s) + tiny(1.0_dp)) return
      call red_children(p, child)
      s = 0.0_dp
      do k = 1, 4
         s = s + adaptive_integral(data, rule, check, gh, child(:, :, k), area/4, depth + 1)
      end do
   end function adaptive_integral

   pure subroutine red_children(p, child)
      real(dp), intent(in) :: p(2, 3)
      real(dp), intent(out) :: child(2, 3, 4)

      real(dp) :: m(2, 3)

      m(:, 1) = 0.5_dp*(p(:, 2) + p(:, 3))
      m(:, 2) = 0.5_dp*(p(:, 3) + p(:, 1))
      m(:, 3) = 0.5_dp*(p(:, 1) + p(:, 2))
      child(:, :, 1) = reshape([p(:, 1), m(:, 3), m(:, 2)], [2, 3])
      child(:, :, 2) = reshape([m(:, 3), p(:, 2), m(:, 1)], [2, 3])
      child(:, :, 3) = reshape([m(:, 2), m(:, 1), p(:, 3)], [2, 3])
      child(:, :, 4) = m
   end subroutine red_children
end module twomem_fem_error
