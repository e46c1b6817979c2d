!> The algebraic flux's patch problems on the finest mesh itself (twomem_estimate_alg_flux with
!> a single mesh, b = J): on the patch of every vertex a of T_J, the RT_p flux with no flux
!> datum whose divergence has the moments of r ψ_a − ∇ρ·∇ψ_a, ρ the Riesz representer of the
!> lifted residual r. Two sources: the exact representer of the coarse solve (∇ρ per triangle,
!> r the evaluated iterate's lifting), or the one-level construction's (twomem_estimate_riesz:
!> ρ̃ nodal and r − r', the lifting of K ρ̃, both held as an evaluated iterate). Patches with a
!> signature use its factor and their classes' integrals, with the arithmetic of the refined
!> levels' patches (twomem_estimate_alg_flux); the others take the generic path
!> (twomem_estimate_generic_patch). Blocks of patches by colours, as the discretization flux.
module twomem_estimate_alg_single
   use omp_lib, only: omp_get_thread_num
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t, corner_of
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_raviart_thomas, only: rt_space_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_patch_factor, only: solve_condensed_factored
   use twomem_estimate_patch_classes, only: patch_table_t, stored_order
   use twomem_estimate_generic_patch, only: generic_scratch_t, solve_generic, patch_links
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, lifting_on, gradients_on
   implicit none
   private

   public :: single_mesh_patches, algebraic_patch_data, factored_patch

contains

   !> sigma(:, t, α) = σ_alg on triangle t of `mesh` (level `level`, vertex colouring `colors`).
   !> The source: r from `source`'s lifting; ∇ρ from `source`'s nodal u when from_nodal (the
   !> one-level construction), else grad_rho(:, t, α). ok is .false. if a patch system is singular.
   subroutine single_mesh_patches(space, shapes, table, mesh, level, colors, scratch, source, from_nodal, grad_rho, &
                                  sigma, ok)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_table_t), intent(in) :: table
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level
      type(coloring_t), intent(in) :: colors
      type(generic_scratch_t), intent(inout) :: scratch(0:)
      type(evaluated_iterate_t), intent(in) :: source
      logical, intent(in) :: from_nodal
      real(dp), intent(in) :: grad_rho(:, :, :)
      real(dp), intent(inout) :: sigma(:, :, :)
      logical, intent(out) :: ok

      integer(ip) :: ib, m, a
      integer :: c, id, me, g
      logical :: patch_ok, signatures
      integer(ip), allocatable :: generic(:)

      ok = .true.
      signatures = allocated(table%levels)
      !$omp parallel default(none) &
      !$omp shared(space, shapes, table, mesh, level, colors, scratch, source, from_nodal, grad_rho, sigma, signatures) &
      !$omp private(c, ib, m, a, id, patch_ok, me, g, generic) reduction(.and.:ok)
      me = omp_get_thread_num()
      !$omp workshare
      sigma = 0.0_dp
      !$omp end workshare
      do c = 1, colors%n_colors
         !$omp do schedule(dynamic, 1)
         do ib = colors%ptr(c), colors%ptr(c + 1) - 1
            call without_signature(table, signatures, level, colors%vertices(colors%block_ptr(ib):colors%block_ptr(ib + 1) - 1), &
                                   generic)
            if (size(generic) > 0) then
               call scratch(me)%gather(space, mesh, generic, patch_ok)
               ok = ok .and. patch_ok
               if (.not. patch_ok) cycle
               ! r and, from the nodal representer, ∇ρ on every gathered triangle
               call scratch(me)%fill(mesh, source, 1)
            end if
            g = 0
            do m = colors%block_ptr(ib), colors%block_ptr(ib + 1) - 1
               a = colors%vertices(m)
               id = 0
               if (signatures) id = table%levels(level)%id(a)
               if (id > 0) then
                  call factored_patch(space, shapes, table, mesh, level, a, id, source, from_nodal, grad_rho, sigma)
               else
                  g = g + 1
                  call generic_patch(space, scratch(me), g, mesh, a, from_nodal, grad_rho, patch_ok)
                  ok = ok .and. patch_ok
               end if
            end do
            if (size(generic) > 0) call scratch(me)%flush(sigma, 1)
         end do
         !$omp end do
      end do
      !$omp end parallel
   end subroutine single_mesh_patches

   !> The vertices of a block whose patches have no signature in `table`, in the block's order.
   pure subroutine without_signature(table, signatures, level, block, generic)
      type(patch_table_t), intent(in) :: table
      logical, intent(in) :: signatures
      integer, intent(in) :: level
      integer(ip), intent(in) :: block(:)
      integer(ip), allocatable, intent(inout) :: generic(:)

      integer :: m, n

      if (allocated(generic)) deallocate (generic)
      if (.not. signatures) then
         allocate (generic, source=block)
         return
      end if
      n = count(table%levels(level)%id(block) == 0)
      allocate (generic(n))
      n = 0
      do m = 1, size(block)
         if (table%levels(level)%id(block(m)) /= 0) cycle
         n = n + 1
         generic(n) = block(m)
      end do
   end subroutine without_signature

   !> r(:, α) on triangle t and s(α) = ∇ψ·∇ρ_α there (∇ψ: the patch vertex's hat gradient).
   pure subroutine source_on(mesh, t, hat, grad_psi, source, from_nodal, grad_rho, r, s)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: hat(2, 3), grad_psi(2)
      type(evaluated_iterate_t), intent(in) :: source
      logical, intent(in) :: from_nodal
      real(dp), intent(in) :: grad_rho(:, :, :)
      real(dp), intent(out) :: r(3, 2), s(2)

      real(dp) :: grad(2, 2)

      call lifting_on(source, mesh, t, r)
      if (from_nodal) then
         call gradients_on(source, mesh, t, hat, grad)
         s = [dot_product(grad_psi, grad(:, 1)), dot_product(grad_psi, grad(:, 2))]
      else
         s = [dot_product(grad_psi, grad_rho(:, t, 1)), dot_product(grad_psi, grad_rho(:, t, 2))]
      end if
   end subroutine source_on

   !> The patch of vertex a with its signature `id`: the data in the signature's order, the
   !> class integrals scaled by the area ratio, summed as the refined levels' patches sum them.
   subroutine factored_patch(space, shapes, table, mesh, level, a, id, source, from_nodal, grad_rho, sigma)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_table_t), intent(in) :: table
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level, id
      integer(ip), intent(in) :: a
      type(evaluated_iterate_t), intent(in) :: source
      logical, intent(in) :: from_nodal
      real(dp), intent(in) :: grad_rho(:, :, :)
      real(dp), intent(inout) :: sigma(:, :, :)

      integer :: ne, k, i, cls, alpha, j, q
      integer(ip) :: t, order(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))
      real(dp) :: rhs_div(space%n_div, size(order), 2), no_flux(2, size(order), 2), hat(2, 3), r(3, 2), s(2)
      real(dp) :: area_factor, ratios(size(order)), c1, c2

      ne = size(order)
      call stored_order(shapes, mesh, level, a, table%levels(level)%order(a), order)
      associate (sig => table%sig(id))
         do k = 1, ne
            t = order(k)
            i = corner_of(mesh, t, a)
            cls = sig%classes(k)
            ratios(k) = shapes%ratio_of(level, t)
            area_factor = 1/ratios(k)**2
            hat = p1_gradients(mesh, t)
            call source_on(mesh, t, hat, hat(:, i), source, from_nodal, grad_rho, r, s)
            rhs_div(:, k, :) = 0.0_dp
            do j = 1, 3
               c1 = area_factor*r(j, 1)
               c2 = area_factor*r(j, 2)
               do q = 1, space%n_div
                  rhs_div(q, k, 1) = rhs_div(q, k, 1) + c1*shapes%bary_psi_q(q, j, i, cls)
                  rhs_div(q, k, 2) = rhs_div(q, k, 2) + c2*shapes%bary_psi_q(q, j, i, cls)
               end do
            end do
            do alpha = 1, 2
               rhs_div(:, k, alpha) = rhs_div(:, k, alpha) - area_factor*s(alpha)*shapes%q_int(:, cls)
            end do
         end do
         ! σ_alg has no flux datum: the factored solve leaves those columns out
         call solve_condensed_factored(space, shapes, sig%classes, ratios, sig%neumann, no_flux, rhs_div, .false., &
                                       sig%factor, order, sigma)
      end associate
   end subroutine factored_patch

   !> The patch of vertex a on the generic path (p: its place in the gathered list, whose slots
   !> hold the source's r and ∇ρ when from_nodal; else ∇ρ comes from grad_rho); σ goes to the
   !> slots' sums.
   pure subroutine generic_patch(space, scratch, p, mesh, a, from_nodal, grad_rho, ok)
      type(rt_space_t), intent(in) :: space
      type(generic_scratch_t), intent(inout) :: scratch
      integer, intent(in) :: p
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: a
      logical, intent(in) :: from_nodal
      real(dp), intent(in) :: grad_rho(:, :, :)
      logical, intent(out) :: ok

      integer :: links(3, mesh%patch_ptr(a + 1) - mesh%patch_ptr(a)), corner(size(links, 2))
      real(dp) :: rhs_div(space%n_div, size(links, 2), 2), no_flux(2, size(links, 2), 2)

      call patch_links(scratch, p, a, mesh%boundary_vertex(a), corner, links)
      associate (slots => scratch%slots(scratch%first(p):scratch%first(p + 1) - 1))
         call algebraic_patch_data(scratch, slots, corner, 1, from_nodal, grad_rho, rhs_div)
         call solve_generic(space, scratch, slots, corner, links, no_flux, rhs_div, .false., ok)
      end associate
   end subroutine generic_patch

   !> The divergence moments rhs_div(:, k, α) of the algebraic flux's patch problem on the
   !> gathered patch whose triangle k is slot slots(k) with the patch vertex its local vertex
   !> corner(k): r from the slots' lifting of data set `set`, ∇ρ from its gradients when
   !> from_nodal, else from grad_rho.
   pure subroutine algebraic_patch_data(scratch, slots, corner, set, from_nodal, grad_rho, rhs_div)
      type(generic_scratch_t), intent(in) :: scratch
      integer, intent(in) :: slots(:), corner(:), set
      logical, intent(in) :: from_nodal
      real(dp), intent(in) :: grad_rho(:, :, :)
      real(dp), intent(out) :: rhs_div(:, :, :)

      integer :: k, i, alpha, sl
      real(dp) :: s(2), g(2, 2)

      associate (ops => scratch%ops)
         do k = 1, size(slots)
            sl = slots(k)
            i = corner(k)
            if (from_nodal) then
               g = scratch%grad(:, :, sl, set)
            else
               g = grad_rho(:, scratch%triangles(sl), :)
            end if
            s = [dot_product(scratch%hat(:, i, sl), g(:, 1)), dot_product(scratch%hat(:, i, sl), g(:, 2))]
            do alpha = 1, 2
               associate (r => scratch%lift(:, alpha, sl, set))
                  rhs_div(:, k, alpha) = ops%bary_psi_q(:, 1, i, sl)*r(1) + ops%bary_psi_q(:, 2, i, sl)*r(2) &
                                         + ops%bary_psi_q(:, 3, i, sl)*r(3) - s(alpha)*ops%q_int(:, sl)
               end associate
            end do
         end do
      end associate
   end subroutine algebraic_patch_data
end module twomem_estimate_alg_single
