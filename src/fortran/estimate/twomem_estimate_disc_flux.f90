!> The discretization flux reconstruction σ_α,disc = Σ_a σ^a_α (paper Def. 4.1): on the patch of
!> every vertex a, the RT_p flux closest to −μ_α ψ_a ∇u_α whose divergence has the moments of
!> g^a_α = (f_α ∓ λ_h(a) − r_α) ψ_a − μ_α ∇u_α·∇ψ_a, with zero normal flux on the patch boundary
!> (except on ∂Ω at boundary vertices). Both membranes share the patch geometry, so each patch
!> is solved once with two right-hand sides. Patches are independent: one OpenMP loop, each
!> thread with its own automatic arrays, and every patch writes its contribution to its own
!> slot (triangle t, local index of a in t), so no two threads touch the same memory; the three
!> slots of a triangle are added afterwards.
module twomem_estimate_disc_flux
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, rt_matrices_t, make_frame
   use twomem_estimate_patch, only: solve_patch, inner_edge, edge_free, edge_neumann
   implicit none
   private

   public :: discretization_flux, load_moments, patch_integrals_t

   !> Integrals of each triangle that turn the patch data into right-hand sides by a few products
   !> (fixed on a mesh, computed once): for the local vertex i of ψ_i = ψ_a,
   !> psi_phi(:, j, i) = ∫ ψ_i φ_j, psi_q(k, i) = ∫ ψ_i q_k, bary_psi_q(k, j, i) = ∫ λ_j ψ_i q_k
   !> (λ_j the barycentric coordinates, which carry r_α) and q_int(k) = ∫ q_k.
   type :: patch_integrals_t
      real(dp), allocatable :: psi_phi(:, :, :, :), psi_q(:, :, :), bary_psi_q(:, :, :, :), q_int(:, :)
   contains
      procedure :: init => integrals_init
   end type patch_integrals_t

contains

   subroutine integrals_init(self, space, mesh)
      class(patch_integrals_t), intent(out) :: self
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh

      type(rt_frame_t) :: frame
      real(dp) :: x(2), w, phi(2, space%n_flux), q(space%n_div)
      integer(ip) :: t
      integer :: k, i, j

      allocate (self%psi_phi(2, space%n_flux, 3, mesh%nt), self%psi_q(space%n_div, 3, mesh%nt), &
                self%bary_psi_q(space%n_div, 3, 3, mesh%nt), self%q_int(space%n_div, mesh%nt))
      !$omp parallel do default(none) shared(self, space, mesh) private(t, frame, x, w, phi, q, k, i, j) &
      !$omp schedule(static)
      do t = 1, mesh%nt
         frame = make_frame(mesh%vertices(:, mesh%triangles(:, t)))
         self%psi_phi(:, :, :, t) = 0.0_dp
         self%psi_q(:, :, t) = 0.0_dp
         self%bary_psi_q(:, :, :, t) = 0.0_dp
         self%q_int(:, t) = 0.0_dp
         do k = 1, space%rule%n
            associate (bary => space%rule%bary(:, k))
               x = matmul(frame%vertices, bary)
               w = space%rule%weights(k)*frame%area
               phi = space%flux_values(frame, x)
               q = space%div_test_values(frame, x)
               self%q_int(:, t) = self%q_int(:, t) + w*q
               do i = 1, 3
                  self%psi_phi(:, :, i, t) = self%psi_phi(:, :, i, t) + w*bary(i)*phi
                  self%psi_q(:, i, t) = self%psi_q(:, i, t) + w*bary(i)*q
                  do j = 1, 3
                     self%bary_psi_q(:, j, i, t) = self%bary_psi_q(:, j, i, t) + w*bary(j)*bary(i)*q
                  end do
               end do
            end associate
         end do
      end do
      !$omp end parallel do
   end subroutine integrals_init

   !> (f_α ψ_i, q_k)_K for every triangle, local vertex i and membrane: the data part of the
   !> patch right-hand sides, fixed on a mesh. Same degree-5 rule as the load vector, so that
   !> the patch data add up to exactly the F_α of the algebraic system.
   subroutine load_moments(space, mesh, data, moments)
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      real(dp), intent(out) :: moments(:, :, :, :)

      type(rt_frame_t) :: frame
      real(dp) :: x(2), w, q(space%n_div)
      integer(ip) :: t
      integer :: k, i, alpha

      !$omp parallel do default(none) shared(space, mesh, data, moments) private(t, frame, k, x, w, q, i, alpha) &
      !$omp schedule(static)
      do t = 1, mesh%nt
         frame = make_frame(mesh%vertices(:, mesh%triangles(:, t)))
         moments(:, :, t, :) = 0.0_dp
         do k = 1, space%rule%n
            x = matmul(frame%vertices, space%rule%bary(:, k))
            w = space%rule%weights(k)*mesh%area(t)
            q = space%div_test_values(frame, x)
            do alpha = 1, 2
               do i = 1, 3
                  moments(:, i, t, alpha) = moments(:, i, t, alpha) + w*data%load(alpha, x)*space%rule%bary(i, k)*q
               end do
            end do
         end do
      end do
      !$omp end parallel do
   end subroutine load_moments

   !> sigma(:, t, α): coefficients of σ_α,disc on triangle t. grad_u(:, t, α) is ∇u_α on t, lambda
   !> the nodal λ_h, r(:, t, α) the residual lifting's vertex values, moments from load_moments.
   !> ok is .false. if some patch system is singular.
   subroutine discretization_flux(space, mesh, matrices, integrals, mu, moments, grad_u, lambda, r, sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      type(rt_matrices_t), intent(in) :: matrices
      type(patch_integrals_t), intent(in) :: integrals
      real(dp), intent(in) :: mu(2), moments(:, :, :, :), grad_u(:, :, :), lambda(:), r(:, :, :)
      real(dp), intent(out) :: sigma(:, :, :)
      logical, intent(out) :: ok

      real(dp), allocatable :: slots(:, :, :, :)
      integer(ip) :: a
      logical :: patch_ok

      allocate (slots(space%n_flux, 3, mesh%nt, 2))
      ok = .true.
      !$omp parallel do default(none) shared(space, mesh, matrices, integrals, mu, moments, grad_u, lambda, r, slots) &
      !$omp private(a, patch_ok) reduction(.and.:ok) schedule(dynamic, 256)
      do a = 1, mesh%nv
         call vertex_patch(space, mesh, matrices, integrals, a, mu, moments, grad_u, lambda(a), r, slots, patch_ok)
         ok = ok .and. patch_ok
      end do
      !$omp end parallel do
      sigma = sum(slots, dim=2)
   end subroutine discretization_flux

   subroutine vertex_patch(space, mesh, matrices, integrals, a, mu, moments, grad_u, lambda_a, r, slots, ok)
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      type(rt_matrices_t), intent(in) :: matrices
      type(patch_integrals_t), intent(in) :: integrals
      integer(ip), intent(in) :: a
      real(dp), intent(in) :: mu(2), moments(:, :, :, :), grad_u(:, :, :), lambda_a, r(:, :, :)
      real(dp), intent(inout) :: slots(:, :, :, :)
      logical, intent(out) :: ok

      integer :: ne, k, m, i, n_inner, alpha
      integer(ip) :: t, e, inner(2*(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))), elements(size(inner)/2)
      integer(ip) :: v(3)
      integer :: links(3, size(elements)), local_a(size(elements))
      real(dp) :: rhs_flux(space%n_flux, size(elements), 2), rhs_div(space%n_div, size(elements), 2)
      real(dp) :: sigma(space%n_flux, size(elements), 2)
      real(dp) :: grad_psi(2), hat_gradients(2, 3)
      real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]

      ne = size(elements)
      n_inner = 0
      do k = 1, ne
         t = mesh%patch_triangles(mesh%patch_ptr(a) + k - 1)
         elements(k) = t
         v = mesh%triangles(:, t)
         hat_gradients = p1_gradients(mesh, t)
         local_a(k) = findloc(v, a, dim=1)
         do m = 1, 3
            e = mesh%triangle_edges(m, t)
            if (m == local_a(k)) then
               ! the patch boundary: closed, except where it is ∂Ω around a boundary vertex
               links(m, k) = merge(edge_free, edge_neumann, mesh%boundary_vertex(a) .and. mesh%boundary_edge(e))
            else if (mesh%boundary_edge(e)) then
               links(m, k) = edge_free
            else
               call inner_edge(inner, n_inner, e, links(m, k))
            end if
         end do

         ! right-hand sides: (−μ ψ_a ∇u, φ_j) and the moments of g^a
         i = local_a(k)
         grad_psi = hat_gradients(:, i)
         do alpha = 1, 2
            rhs_flux(:, k, alpha) = -mu(alpha)*matmul(grad_u(:, t, alpha), integrals%psi_phi(:, :, i, t))
            rhs_div(:, k, alpha) = moments(:, i, t, alpha) + lambda_sign(alpha)*lambda_a*integrals%psi_q(:, i, t) &
                                   - matmul(integrals%bary_psi_q(:, :, i, t), r(:, t, alpha)) &
                                   - mu(alpha)*dot_product(grad_u(:, t, alpha), grad_psi)*integrals%q_int(:, t)
         end do
      end do

      call solve_patch(space, matrices, elements, links, rhs_flux, rhs_div, sigma, ok)
      do k = 1, ne
         t = mesh%patch_triangles(mesh%patch_ptr(a) + k - 1)
         slots(:, local_a(k), t, :) = sigma(:, k, :)
      end do
   end subroutine vertex_patch
end module twomem_estimate_disc_flux
