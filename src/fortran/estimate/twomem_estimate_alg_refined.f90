!> The multilevel algebraic flux's patch problems on the refined levels T_{b+1}..T_J
!> (twomem_estimate_alg_flux): on the patch of every vertex a of T_{j−1}, the RT_p problem on
!> its triangles' children in T_j with divergence (I − Π_{j−1})(r_α ψ_a − ∇ρ_α·∇ψ_a), and the
!> P2 projections of r_α on the coarser levels that these data read. On a refined patch ψ_a is
!> 1, 1/2 or 0 at the children's corners and the children sit at fixed places in their parent's
!> frame, so the divergence data of child c of a coarse triangle t, a its local vertex k, are the
!> class tables of t for (k, c) (twomem_estimate_shapes) applied to the child's P2 field (or r
!> on T_J) and, above the first refined level, to Π_coarse(r ψ_a) in t's basis, times the child's
!> area ratio: no coordinates are read per child, only ∇ψ_a per coarse triangle on the first
!> level (whose smooth part ∇ρ·∇ψ_a is constant there). A refined patch's multipliers are
!> numbered so that those inside each coarse triangle form a block (twomem_estimate_patch).
module twomem_estimate_alg_refined
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t, triangle_class, n_p2
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_patch, only: solve_patch, link_edge, on_opposite_edge
   use twomem_estimate_patch_factor, only: solve_condensed_factored
   use twomem_estimate_patch_classes, only: patch_table_t, stored_order, edge_signs
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, lifting_on
   implicit none
   private

   public :: p2_field_t, project_p2, level_patches

   !> A broken P2 field for both membranes: coefficients (n_p2, nt, 2) in each triangle's monomials.
   type :: p2_field_t
      real(dp), allocatable :: c(:, :, :)
   end type p2_field_t

contains

   !> r_α's L² projection onto P2 of every triangle of T_first..T_{J−1}, coarsest last: that of
   !> a coarse triangle is the sum of the projections of its four children's fields (P1 r on
   !> T_J, their P2 projections above), the class operators p2_from_p1 and p2_from_p2.
   subroutine project_p2(shapes, hierarchy, first, iterate, p2)
      type(shape_classes_t), intent(in) :: shapes
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: first
      type(evaluated_iterate_t), intent(in) :: iterate
      type(p2_field_t), intent(inout) :: p2(first:)

      integer :: l, c, cls, alpha, j
      integer(ip) :: t, child
      real(dp) :: ratio, r(3, 2)

      do l = ubound(p2, 1) - 1, first, -1
         !$omp parallel do default(none) shared(shapes, hierarchy, p2, iterate, l) &
         !$omp private(t, c, cls, ratio, child, alpha, j, r) schedule(static)
         do t = 1, hierarchy%meshes(l)%nt
            call triangle_class(l, t, cls, ratio)
            p2(l)%c(:, t, :) = 0.0_dp
            do c = 1, 4
               child = 4*(t - 1) + c
               if (l + 1 == ubound(p2, 1)) call lifting_on(iterate, hierarchy%meshes(l + 1), child, r)
               do alpha = 1, 2
                  if (l + 1 == ubound(p2, 1)) then
                     do j = 1, 3
                        p2(l)%c(:, t, alpha) = p2(l)%c(:, t, alpha) + r(j, alpha)*shapes%p2_from_p1(:, j, c, cls)
                     end do
                  else
                     do j = 1, n_p2
                        p2(l)%c(:, t, alpha) = p2(l)%c(:, t, alpha) + p2(l + 1)%c(j, child, alpha)*shapes%p2_from_p2(:, j, c, cls)
                     end do
                  end if
               end do
            end do
         end do
         !$omp end parallel do
      end do
   end subroutine project_p2

   !> The patch problems of one refined level: patches of the vertices of `coarse` (coloured by
   !> `colors`), triangles of `fine`, its red refinement, level `level` of the hierarchy.
   !> `first`: the data are r ψ_a − ∇ρ·∇ψ_a (grad_rho on the coarse triangles), otherwise
   !> (I − Π_coarse)(r ψ_a).
   subroutine level_patches(space, shapes, table, coarse, fine, level, colors, first, grad_rho, p2_coarse, p2_fine, &
                            iterate, sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_table_t), intent(in) :: table
      type(mesh_t), intent(in) :: coarse, fine
      integer, intent(in) :: level
      type(coloring_t), intent(in) :: colors
      logical, intent(in) :: first
      real(dp), intent(in) :: grad_rho(:, :, :)
      type(p2_field_t), intent(in) :: p2_coarse, p2_fine
      !> its residual lifting on T_J: r where p2_fine is not stored (the finest level)
      type(evaluated_iterate_t), intent(in) :: iterate
      real(dp), intent(inout) :: sigma(:, :, :)
      logical, intent(out) :: ok

      integer(ip) :: a, ib, m
      integer :: c
      logical :: patch_ok

      ok = .true.
      !$omp parallel default(none) &
      !$omp shared(space, shapes, table, coarse, fine, level, colors, first, grad_rho, p2_coarse, p2_fine, iterate, sigma) &
      !$omp private(a, ib, m, c, patch_ok) reduction(.and.:ok)
      !$omp workshare
      sigma = 0.0_dp
      !$omp end workshare
      do c = 1, colors%n_colors
         !$omp do schedule(dynamic, 1)
         do ib = colors%ptr(c), colors%ptr(c + 1) - 1
            do m = colors%block_ptr(ib), colors%block_ptr(ib + 1) - 1
               a = colors%vertices(m)
               call coarse_patch(space, shapes, table, coarse, fine, level, a, first, grad_rho, p2_coarse, p2_fine, &
                                 iterate, sigma, patch_ok)
               ok = ok .and. patch_ok
            end do
         end do
         !$omp end do
      end do
      !$omp end parallel
   end subroutine level_patches

   !> One patch of level_patches: with its signature in `table` (triangles in the signature's
   !> order, its edges and factor), or assembled and factorized on its own without one.
   subroutine coarse_patch(space, shapes, table, coarse, fine, level, a, first, grad_rho, p2_coarse, p2_fine, &
                           iterate, sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_table_t), intent(in) :: table
      type(mesh_t), intent(in) :: coarse, fine
      integer, intent(in) :: level
      integer(ip), intent(in) :: a
      logical, intent(in) :: first
      real(dp), intent(in) :: grad_rho(:, :, :)
      type(p2_field_t), intent(in) :: p2_coarse, p2_fine
      !> its residual lifting on T_J: r where p2_fine is not stored (the finest level)
      type(evaluated_iterate_t), intent(in) :: iterate
      real(dp), intent(inout) :: sigma(:, :, :)
      logical, intent(out) :: ok

      integer, parameter :: max_inner_per_triangle = 9, n_children = 4
      integer :: n_coarse, ne, k, kc, c, m, i, alpha, local_a, n_inner, n_blocks
      integer(ip) :: t, child, e, v(3), children(n_children*(coarse%patch_ptr(a + 1) - coarse%patch_ptr(a)))
      integer(ip) :: inner(max_inner_per_triangle*(coarse%patch_ptr(a + 1) - coarse%patch_ptr(a)))
      integer :: links(3, size(children)), classes(size(children))
      real(dp) :: ratios(size(children)), signs(3*space%n_trace, size(children))
      real(dp) :: rhs_flux(space%n_flux, size(children), 2), rhs_div(space%n_div, size(children), 2)
      real(dp) :: patch_sigma(space%n_flux, size(children), 2)
      real(dp) :: coarse_part(space%n_div, 2), smooth(2), hat_gradients(2, 3), area_factor, ratio, ratio_level, r(3, 2)
      integer :: cls, id, coarse_level
      integer(ip) :: order(coarse%patch_ptr(a + 1) - coarse%patch_ptr(a))

      n_coarse = coarse%patch_ptr(a + 1) - coarse%patch_ptr(a)
      ne = 0
      n_inner = 0
      n_blocks = 0
      coarse_level = level - 1
      ratio_level = 2.0_dp**level
      id = 0
      if (allocated(table%levels)) id = table%levels(coarse_level)%id(a)
      if (id > 0) then
         call stored_order(shapes, coarse, coarse_level, a, table%levels(coarse_level)%order(a), order)
      else
         order = coarse%patch_triangles(coarse%patch_ptr(a):coarse%patch_ptr(a + 1) - 1)
      end if
      if (id == 0) then
         ! the inner edges of each coarse triangle (its middle child's edges) first, one block each
         n_blocks = n_coarse
         do kc = 1, n_coarse
            t = order(kc)
            do m = 1, 3
               n_inner = n_inner + 1
               inner(n_inner) = fine%triangle_edges(m, 4*t)
            end do
         end do
      end if
      do kc = 1, n_coarse
         t = order(kc)
         local_a = findloc(coarse%triangles(:, t), a, dim=1)
         call triangle_class(coarse_level, t, cls, ratio)
         if (first) then
            ! ∇ρ·∇ψ_a, constant on t
            hat_gradients = p1_gradients(coarse, t)
            smooth = [dot_product(hat_gradients(:, local_a), grad_rho(:, t, 1)), &
                      dot_product(hat_gradients(:, local_a), grad_rho(:, t, 2))]
         else
            ! Π_coarse(r ψ_a) on t, in the divergence basis of t: r is P2 there, and the projection
            ! of each monomial times ψ_a is its class's
            coarse_part = 0.0_dp
            do alpha = 1, 2
               do i = 1, n_p2
                  coarse_part(:, alpha) = coarse_part(:, alpha) + p2_coarse%c(i, t, alpha)*shapes%div_proj(:, i, local_a, cls)
               end do
            end do
         end if
         do c = 1, n_children
            ne = ne + 1
            child = 4*(t - 1) + c
            children(ne) = child
            if (id > 0) then
               ! the signature holds the classes and the relative trace signs
               classes(ne) = table%sig(id)%classes(ne)
               ratios(ne) = ratio_level
            else
               v = fine%triangles(:, child)
               call triangle_class(level, child, classes(ne), ratios(ne))
               call edge_signs(space%n_trace, v, signs(:, ne))
            end if
            do m = 1, 3
               if (id > 0) exit
               e = fine%triangle_edges(m, child)
               call link_edge(fine%boundary_edge(e), on_opposite_edge(.true., local_a, c, m), &
                              coarse%boundary_vertex(a), e, inner, n_inner, links(m, ne))
            end do
            ! the moments of r ψ_a on the child (r linear on T_J, P2 in the child's monomials
            ! above) and of the smooth part (∇ρ·∇ψ_a constant, or Π_coarse(r ψ_a) in t's q_l): the
            ! tables of t's class for local vertex a and child c, scaled by the child's area, are
            ! exact; no geometry is needed
            area_factor = 1/ratios(ne)**2
            rhs_div(:, ne, :) = 0.0_dp
            if (allocated(p2_fine%c)) then
               call add_moments(space%n_div, n_p2, shapes%child_mono_psi_q(:, :, local_a, c, cls), area_factor, &
                                p2_fine%c(:, child, :), rhs_div(:, ne, :))
            else
               call lifting_on(iterate, fine, child, r)
               call add_moments(space%n_div, 3, shapes%child_bary_psi_q(:, :, local_a, c, cls), area_factor, r, &
                                rhs_div(:, ne, :))
            end if
            if (first) then
               do alpha = 1, 2
                  rhs_div(:, ne, alpha) = rhs_div(:, ne, alpha) - area_factor*smooth(alpha)*shapes%q_int(:, classes(ne))
               end do
            else
               call add_moments(space%n_div, space%n_div, shapes%child_q_coarse(:, :, c, cls), -area_factor, coarse_part, &
                                rhs_div(:, ne, :))
            end if
         end do
      end do
      if (id > 0) then
         ! σ_alg has no flux datum: the factored solve leaves those columns out (rhs_flux unread)
         associate (sig => table%sig(id))
            call solve_condensed_factored(space, shapes, sig%classes, ratios(1:ne), sig%neumann, rhs_flux(1:2, :, :), &
                                          rhs_div, .false., sig%factor, children, sigma)
         end associate
         ok = .true.
      else
         rhs_flux = 0.0_dp
         call solve_patch(space, shapes, classes, ratios, signs, links, rhs_flux, rhs_div, .false., n_blocks, &
                          patch_sigma, ok)
         do k = 1, ne
            sigma(:, children(k), :) = sigma(:, children(k), :) + patch_sigma(:, k, :)
         end do
      end if
   end subroutine coarse_patch

   !> rhs(:, α) += factor Σ_j coef(j, α) moments(:, j) for both membranes (one pass over the
   !> moments): the moments of the fields with coefficients coef in a basis whose moments, at
   !> the class size, are `moments`, scaled by `factor`.
   pure subroutine add_moments(nd, nb, moments, factor, coef, rhs)
      integer, intent(in) :: nd, nb
      real(dp), intent(in) :: moments(nd, nb), factor, coef(:, :)
      real(dp), intent(inout) :: rhs(:, :)

      integer :: j, q
      real(dp) :: c1, c2

      do j = 1, nb
         c1 = factor*coef(j, 1)
         c2 = factor*coef(j, 2)
         do q = 1, nd
            rhs(q, 1) = rhs(q, 1) + c1*moments(q, j)
            rhs(q, 2) = rhs(q, 2) + c2*moments(q, j)
         end do
      end do
   end subroutine add_moments
end module twomem_estimate_alg_refined
