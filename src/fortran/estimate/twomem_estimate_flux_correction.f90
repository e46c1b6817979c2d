!> A divergence-free correction of the discretization flux (docs/method.md §3, *Sharper
!> bounds*, 4). The patch problems make each vertex's flux σ^a as close as they can to
!> −μ_α ψ_a ∇u_αh, but nothing makes their sum σ_α the closest to −μ_α ∇u_αh among the fields
!> with its divergence: that is a global problem. Adding curl φ_α = (∂₂φ_α, −∂₁φ_α) with φ_α
!> continuous P1 and zero on ∂Ω changes neither the divergence (it is zero on every triangle)
!> nor the H(div) conformity (its normal component on an edge is φ_α's tangential derivative,
!> the same from both sides), and curl φ_α is constant on each triangle, a field of RT0 ⊂ RT1:
!> every step of the bound's proof holds for σ_α + curl φ_α as for σ_α, whatever φ_α is. The
!> flux term ‖μ_α^{−½}(μ_α∇u_αh + σ_α + curl φ_α)‖² is a quadratic function of φ_α whose
!> minimizer solves K φ_α = b_α, K the stiffness on the interior vertices
!> ((curl φ, curl ψ) = (∇φ, ∇ψ)) and b_α,i = −(σ_α, curl ψ_i) (the part of μ_α∇u_αh vanishes:
!> (∇u, curl ψ) = 0 for ψ ∈ H¹_0). Conjugate gradients from φ_α = 0 lower that quadratic at
!> every iteration, and the bound holds after any number of them. The excess they remove sits
!> on the mesh scale (each patch flux is locally optimal already), so a few unpreconditioned
!> iterations take nearly all of it (RT0 on a disk of 6.7·10⁵ triangles: effectivity 2.98 before,
!> 1.23 after 5 iterations, 1.190 after 20, 1.188 converged), with the same iterates on any
!> number of ranks. On RT1 the gain is small (its patch fluxes come near the optimum already);
!> on RT0 it is most of the flux term's excess.
!> Distributed: b is summed over the ranks at shared unknowns like K's products, and each
!> rank corrects its own triangles, all of whose vertices it holds.
module twomem_estimate_flux_correction
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_linalg_halo, only: halo_t
   use twomem_linalg_operators, only: summed_csr_operator_t, identity_preconditioner_t, &
      distributed_product_t
   use twomem_linalg_pcg, only: pcg_solve, pcg_options_t, pcg_monitor_t
   use twomem_estimate_raviart_thomas, only: rt_frame_t, frame_of
   implicit none
   private

   public :: correct_flux

   !> the conjugate gradients stop at this relative residual ...
   real(dp), parameter :: correction_rtol = 1.0e-2_dp
   !> ... or after this many iterations: RT0's excess needs about 20 (on the disk of 6.7·10⁵
   !> triangles, effectivity 1.230 after 5, 1.199 after 10, 1.190 after 20, 1.188 converged);
   !> RT1's small gain is 90% taken after 5 (1.01668 after 5, 1.01657 after 20, 1.01655
   !> converged, from 1.01773), at a quarter of the iterations' cost
   integer, parameter :: correction_max_it(0:1) = [20, 5]

contains

   !> sigma(:, t, α) += curl φ_α on this rank's own triangles (order: the RT space's), φ_α from
   !> conjugate gradients on K φ_α = b_α, at most max_iterations (default: correction_max_it
   !> of the order). iterations: per membrane. Collective.
   subroutine correct_flux(order, mesh, p, halo, sigma, iterations, err, max_iterations)
      integer, intent(in) :: order
      type(mesh_t), intent(in) :: mesh
      type(discrete_problem_t), target, intent(in) :: p
      type(halo_t), target, intent(inout) :: halo
      real(dp), intent(inout) :: sigma(:, :, :)
      integer, intent(out) :: iterations(2)
      type(error_t), allocatable, intent(out) :: err
      integer, intent(in), optional :: max_iterations

      type(summed_csr_operator_t) :: k_op
      type(distributed_product_t) :: dot
      type(pcg_options_t) :: options
      type(pcg_monitor_t) :: monitor
      type(identity_preconditioner_t) :: none
      real(dp), allocatable :: b(:, :), phi(:, :)
      integer :: alpha

      k_op%a => p%stiffness
      k_op%halo => halo
      dot%comm = halo%comm
      dot%owned = halo%owned
      options%max_it = correction_max_it(order)
      if (present(max_iterations)) options%max_it = max_iterations
      options%rtol = correction_rtol
      allocate (b(p%n, 2), phi(p%n, 2))
      call curl_moments(order, mesh, p, sigma, b)
      phi = 0.0_dp
      do alpha = 1, 2
         call halo%add(b(:, alpha))
         call pcg_solve(k_op, none, dot, b(:, alpha), phi(:, alpha), options, monitor, err)
         if (allocated(err)) return
         iterations(alpha) = monitor%iterations
      end do
      call add_curl(mesh, p, phi, sigma)
   end subroutine correct_flux

   !> b(i, α) = −(σ_α, curl ψ_i) over this rank's own triangles: curl ψ_i is constant on each,
   !> so only ∫_K σ_α enters, |K| (c_1, c_2) plus, for RT1, the second moments of ξ times c_7,
   !> c_8 (the linear monomials integrate to zero about the barycentre). Each triangle's share
   !> of its three vertices first, then each unknown's sum over its patch (threaded, no scatter).
   subroutine curl_moments(order, mesh, p, sigma, b)
      integer, intent(in) :: order
      type(mesh_t), intent(in) :: mesh
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: sigma(:, :, :)
      real(dp), intent(out) :: b(:, :)

      real(dp), allocatable :: share(:, :, :)
      type(rt_frame_t) :: frame
      real(dp) :: hat(2, 3), q(2, 3), s(2), m20, m11, m02, area, acc(2)
      integer(ip) :: t, i, a, j
      integer :: k, alpha

      allocate (share(2, 3, mesh%nt_owned))
      !$omp parallel default(none) shared(order, mesh, p, sigma, b, share) &
      !$omp private(t, i, a, j, k, alpha, frame, hat, q, s, m20, m11, m02, area, acc)
      !$omp do schedule(static)
      do t = 1, mesh%nt_owned
         area = mesh%area(t)
         if (order == 1) then
            ! the vertices in the basis's scaled coordinates ξ
            frame = frame_of(mesh%vertices, mesh%triangles(:, t))
            do k = 1, 3
               q(:, k) = (frame%vertices(:, k) - frame%centre)/frame%scale
            end do
            m20 = area/12*(q(1, 1)**2 + q(1, 2)**2 + q(1, 3)**2)
            m11 = area/12*(q(1, 1)*q(2, 1) + q(1, 2)*q(2, 2) + q(1, 3)*q(2, 3))
            m02 = area/12*(q(2, 1)**2 + q(2, 2)**2 + q(2, 3)**2)
         end if
         hat = p1_gradients(mesh, t)
         do alpha = 1, 2
            s = area*sigma(1:2, t, alpha)
            if (order == 1) then
               s(1) = s(1) + sigma(7, t, alpha)*m20 + sigma(8, t, alpha)*m11
               s(2) = s(2) + sigma(7, t, alpha)*m11 + sigma(8, t, alpha)*m02
            end if
            do k = 1, 3
               share(alpha, k, t) = hat(1, k)*s(2) - hat(2, k)*s(1)
            end do
         end do
      end do
      !$omp end do
      !$omp do schedule(static)
      do i = 1, p%n
         a = p%interior(i)
         acc = 0.0_dp
         do j = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
            t = mesh%patch_triangles(j)
            if (t > mesh%nt_owned) cycle
            do k = 1, 3
               if (mesh%triangles(k, t) == a) acc = acc + share(:, k, t)
            end do
         end do
         b(i, :) = acc
      end do
      !$omp end do
      !$omp end parallel
   end subroutine curl_moments

   !> sigma(1:2, t, α) += curl φ_α on this rank's own triangles (φ_α zero on the boundary).
   subroutine add_curl(mesh, p, phi, sigma)
      type(mesh_t), intent(in) :: mesh
      type(discrete_problem_t), intent(in) :: p
      real(dp), intent(in) :: phi(:, :)
      real(dp), intent(inout) :: sigma(:, :, :)

      real(dp) :: hat(2, 3), g(2, 2)
      integer(ip) :: t, i
      integer :: k

      !$omp parallel do default(none) shared(mesh, p, phi, sigma) private(t, i, k, hat, g) schedule(static)
      do t = 1, mesh%nt_owned
         hat = p1_gradients(mesh, t)
         g = 0.0_dp
         do k = 1, 3
            i = p%unknown(mesh%triangles(k, t))
            if (i == 0) cycle
            g(:, 1) = g(:, 1) + phi(i, 1)*hat(:, k)
            g(:, 2) = g(:, 2) + phi(i, 2)*hat(:, k)
         end do
         sigma(1, t, :) = sigma(1, t, :) + g(2, :)
         sigma(2, t, :) = sigma(2, t, :) - g(1, :)
      end do
      !$omp end parallel do
   end subroutine add_curl

end module twomem_estimate_flux_correction
