!> The energy error |||u − u_h|||_K = (Σ_α μ_α ‖∇(u_α − u_αh)‖²_K)^{1/2} per element, against a
!> known exact solution. The exact gradients have a kink on the free boundary (and wherever
!> the data jump), which no fixed rule integrates well on the elements it crosses; so each
!> element is integrated with the 16-point degree-8 rule and, where that disagrees with the
!> 7-point degree-5 rule, split into its four red children, recursively (at most `max_depth`
!> times). On smooth elements the two rules agree to round-off and one comparison suffices.
!> A run that follows the error through its Newton iterates uses `exact_energy_t`: since ∇u_αh
!> is constant on each element, ‖∇u_α − ∇u_αh‖²_K = ‖∇u_α − m_α‖²_K + |K| |m_α − ∇u_αh|² with
!> m_α the mean of ∇u_α on K, so the exact solution's part (m_α and the spread ‖∇u_α − m_α‖²_K)
!> is integrated once and every later error costs a few operations per element. Both terms
!> are non-negative: no cancellation, whatever the size of the error. Its rule agreement is
!> judged on the spread alone, which is also the safer test: judged on the whole integrand, a
!> large error lets an element on the free boundary pass with the two rules agreeing by
!> accident (found 1.6e-4 off on one element; the cached part was within 1e-7 of a uniform
!> 128² subdivision). `energy_error_per_element` integrates one field directly.
module twomem_fem_error
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: red_children
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_fem_assembly, only: p1_gradients
   use twomem_fem_discrete, only: discrete_problem_t
   implicit none
   private

   public :: energy_error_per_element, exact_energy_t

   !> The exact solution's part of the energy error on each element of one mesh for one problem
   !> (`init`): the mean exact gradients and their spread, and the problem's μ_α.
   type :: exact_energy_t
      private
      integer(ip) :: nt = -1
      real(dp) :: mu(2) = 0.0_dp
      !> mean(:, α, t) = m_α on t, spread(t) = Σ_α μ_α ‖∇u_α − m_α‖²_t (only the weighted sum
      !> is ever read: one number per element instead of two, 16 MB at 10⁶ vertices)
      real(dp), allocatable :: mean(:, :, :), spread(:)
   contains
      procedure :: init => integrate_exact_part
      procedure :: ready
      procedure :: per_element => cached_per_element
      procedure :: squared_total
      procedure :: free => free_exact_part
   end type exact_energy_t

   integer, parameter :: max_depth = 5
   !> relative agreement at which an element's integral is accepted
   real(dp), parameter :: accept_rtol = 1.0e-8_dp
   !> points of the largest rule used here (degree 8: 16), for the gradients kept per element
   integer, parameter :: max_points = 16

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

   !> The integrated part goes (`ready` is .false. until the next `init`).
   subroutine free_exact_part(self)
      class(exact_energy_t), intent(inout) :: self

      if (allocated(self%mean)) deallocate (self%mean, self%spread)
      self%nt = -1
   end subroutine free_exact_part

   !> Whether `init` has integrated a mesh of this size (the mesh its caller keeps using).
   pure logical function ready(self, mesh)
      class(exact_energy_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh

      ready = self%nt == mesh%nt
   end function ready

   !> energy_error_per_element for the mesh and problem of `init`, from its integrated part.
   function cached_per_element(self, mesh, u1, u2) result(err_k)
      class(exact_energy_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u1(:), u2(:)
      real(dp) :: err_k(mesh%nt)

      real(dp) :: grad(2, 3), gh(2, 2)
      integer(ip) :: t

      !$omp parallel do default(none) shared(self, mesh, u1, u2, err_k) private(t, grad, gh) schedule(static)
      do t = 1, mesh%nt
         grad = p1_gradients(mesh, t)
         gh(:, 1) = matmul(grad, u1(mesh%triangles(:, t)))
         gh(:, 2) = matmul(grad, u2(mesh%triangles(:, t)))
         err_k(t) = sqrt(squared_on(self, mesh, t, gh))
      end do
      !$omp end parallel do
   end function cached_per_element

   !> Σ_K |||u − u_h|||²_K over this rank's own triangles for the Newton iterate x = [X1; X2; X3]
   !> of problem p (boundary values g and 0), straight from x: the error of every recorded
   !> iterate, with no mesh-sized array. By blocks of triangles in a fixed order, so that the
   !> sum does not depend on the threads.
   function squared_total(self, mesh, p, x) result(total)
      class(exact_energy_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: x(:)
      real(dp) :: total

      integer(ip), parameter :: block = 1024
      real(dp), allocatable :: partial(:)
      real(dp) :: grad(2, 3), gh(2, 2), uv(3, 2)
      integer(ip) :: t, b, n_blocks, i
      integer :: k

      n_blocks = (mesh%nt_owned + block - 1)/block
      allocate (partial(n_blocks))
      !$omp parallel do default(none) shared(self, mesh, p, x, n_blocks, partial) private(b, t, k, i, grad, gh, uv) &
      !$omp schedule(static)
      do b = 1, n_blocks
         partial(b) = 0.0_dp
         do t = (b - 1)*block + 1, min(b*block, mesh%nt_owned)
            do k = 1, 3
               i = p%unknown(mesh%triangles(k, t))
               if (i > 0) then
                  uv(k, :) = [x(i), x(p%n + i)]
               else
                  uv(k, :) = [p%g, 0.0_dp]
               end if
            end do
            grad = p1_gradients(mesh, t)
            gh(:, 1) = matmul(grad, uv(:, 1))
            gh(:, 2) = matmul(grad, uv(:, 2))
            partial(b) = partial(b) + squared_on(self, mesh, t, gh)
         end do
      end do
      !$omp end parallel do
      total = sum(partial)
   end function squared_total

   !> |||u − u_h|||²_t from the integrated exact part and ∇u_αh = gh(:, α): the weighted spread
   !> plus |t| Σ_α μ_α |m_α − ∇u_αh|², two non-negative terms.
   pure real(dp) function squared_on(self, mesh, t, gh)
      type(exact_energy_t), intent(in) :: self
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: gh(2, 2)

      squared_on = self%spread(t) + mesh%area(t)*(self%mu(1)*sum((self%mean(:, 1, t) - gh(:, 1))**2) + &
                                                 self%mu(2)*sum((self%mean(:, 2, t) - gh(:, 2))**2))
   end function squared_on

   !> The mean gradients and spreads of every element. The adaptive rule integrates ∇u_α − m0_α
   !> and |∇u_α − m0_α|² with m0_α the degree-8 mean on the whole element; the exact mean and
   !> spread follow as m_α = m0_α + E_α/|K| and ‖∇u_α − m_α‖² = ‖∇u_α − m0_α‖² − |E_α|²/|K|.
   subroutine integrate_exact_part(self, mesh, data)
      class(exact_energy_t), intent(inout) :: self
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data

      type(quadrature_t) :: rule, check
      real(dp) :: p(2, 3), m0(2, 2), moments(3, 2), g(2, 2, max_points), spread(2)
      integer(ip) :: t
      integer :: q, alpha

      if (allocated(self%mean)) deallocate (self%mean, self%spread)
      allocate (self%mean(2, 2, mesh%nt), self%spread(mesh%nt))
      self%nt = mesh%nt
      self%mu = [data%mu1, data%mu2]
      rule = triangle_rule(8)
      check = triangle_rule(5)
      !$omp parallel do default(none) shared(self, mesh, data, rule, check) &
      !$omp private(t, p, m0, moments, g, q, alpha, spread) schedule(dynamic, 64)
      do t = 1, mesh%nt
         p = mesh%vertices(:, mesh%triangles(:, t))
         ! the exact gradients at the rule's points once, for the mean and the element's moments
         call exact_gradients(data, rule, p, g)
         m0 = 0.0_dp
         do q = 1, rule%n
            m0 = m0 + rule%weights(q)*g(:, :, q)
         end do
         moments = refined_moments(data, rule, check, m0, p, mesh%area(t), 0, &
                                   moments_of(rule, g(:, :, 1:rule%n), m0, mesh%area(t)))
         do alpha = 1, 2
            self%mean(:, alpha, t) = m0(:, alpha) + moments(2:3, alpha)/mesh%area(t)
            spread(alpha) = max(0.0_dp, moments(1, alpha) - sum(moments(2:3, alpha)**2)/mesh%area(t))
         end do
         self%spread(t) = self%mu(1)*spread(1) + self%mu(2)*spread(2)
      end do
      !$omp end parallel do
   end subroutine integrate_exact_part

   !> ∫_T [|∇u_α − m0_α|², ∇u_α − m0_α] for α = 1, 2 (columns) by the rule on T.
   function rule_moments(data, rule, m0, p, area) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: m0(2, 2), p(2, 3), area
      real(dp) :: s(3, 2)

      real(dp) :: g(2, 2, max_points)

      call exact_gradients(data, rule, p, g)
      s = moments_of(rule, g(:, :, 1:rule%n), m0, area)
   end function rule_moments

   !> g(:, α, q) = ∇u_α at the rule's points on the triangle with corners p.
   subroutine exact_gradients(data, rule, p, g)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: p(2, 3)
      real(dp), intent(out) :: g(:, :, :)

      real(dp) :: x(2, max_points)
      integer :: q

      do q = 1, rule%n
         x(:, q) = matmul(p, rule%bary(:, q))
      end do
      call data%exact_gradients_at(x(:, 1:rule%n), g(:, :, 1:rule%n))
   end subroutine exact_gradients

   !> rule_moments from the exact gradients g(:, α, q) at the rule's points.
   pure function moments_of(rule, g, m0, area) result(s)
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: g(:, :, :), m0(2, 2), area
      real(dp) :: s(3, 2)

      real(dp) :: d(2)
      integer :: q, alpha

      s = 0.0_dp
      do q = 1, rule%n
         do alpha = 1, 2
            d = g(:, alpha, q) - m0(:, alpha)
            s(:, alpha) = s(:, alpha) + rule%weights(q)*[sum(d**2), d]
         end do
      end do
      s = area*s
   end function moments_of

   !> rule_moments on T where it agrees with the check rule, else the sum over T's children.
   !> Agreement: the μ-weighted spreads to accept_rtol relative, the √μ-weighted first moments
   !> to accept_rtol relative to their scale (Cauchy–Schwarz: |∫ d| ≤ (|T| ∫ |d|²)^{1/2}).
   recursive function adaptive_moments(data, rule, check, m0, p, area, depth) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule, check
      real(dp), intent(in) :: m0(2, 2), p(2, 3), area
      integer, intent(in) :: depth
      real(dp) :: s(3, 2)

      s = refined_moments(data, rule, check, m0, p, area, depth, rule_moments(data, rule, m0, p, area))
   end function adaptive_moments

   !> adaptive_moments once the rule's moments `own` on T are known.
   recursive function refined_moments(data, rule, check, m0, p, area, depth, own) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule, check
      real(dp), intent(in) :: m0(2, 2), p(2, 3), area, own(3, 2)
      integer, intent(in) :: depth
      real(dp) :: s(3, 2)

      real(dp) :: c(3, 2), child(2, 3, 4), spread, spread_gap, first_gap
      integer :: k

      s = own
      if (depth >= max_depth) return
      c = rule_moments(data, check, m0, p, area) - s
      spread = data%mu1*s(1, 1) + data%mu2*s(1, 2)
      spread_gap = data%mu1*abs(c(1, 1)) + data%mu2*abs(c(1, 2))
      first_gap = sqrt(data%mu1)*norm2(c(2:3, 1)) + sqrt(data%mu2)*norm2(c(2:3, 2))
      if (spread_gap <= accept_rtol*spread + tiny(1.0_dp) .and. &
          first_gap <= accept_rtol*sqrt(area*spread) + tiny(1.0_dp)) return
      child = red_children(p)
      s = 0.0_dp
      do k = 1, 4
         s = s + adaptive_moments(data, rule, check, m0, child(:, :, k), area/4, depth + 1)
      end do
   end function refined_moments

   !> ∫_T Σ_α μ_α |∇u_α − g_α|² by the rule on T.
   real(dp) function rule_integral(data, rule, gh, p, area) result(s)
      class(problem_data_t), intent(in) :: data
      type(quadrature_t), intent(in) :: rule
      real(dp), intent(in) :: gh(2, 2), p(2, 3), area

      real(dp) :: gx(2, 2, max_points)
      integer :: q

      call exact_gradients(data, rule, p, gx)
      s = 0.0_dp
      do q = 1, rule%n
         s = s + rule%weights(q)*(data%mu1*sum((gx(:, 1, q) - gh(:, 1))**2) + &
                                  data%mu2*sum((gx(:, 2, q) - gh(:, 2))**2))
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
      child = red_children(p)
      s = 0.0_dp
      do k = 1, 4
         s = s + adaptive_integral(data, rule, check, gh, child(:, :, k), area/4, depth + 1)
      end do
   end function adaptive_integral
end module twomem_fem_error
