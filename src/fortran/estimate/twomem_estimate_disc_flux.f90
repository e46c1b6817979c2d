!> The discretization flux reconstruction σ_α,disc = Σ_a σ^a_α (paper Def. 4.1): on the patch of
!> every vertex a, the RT_p flux closest to −μ_α ψ_a ∇u_α whose divergence has the moments of
!> g^a_α = (f_α ∓ λ_h(a) w_a − r_α) ψ_a − μ_α ∇u_α·∇ψ_a (w_a = 1 but with `estimate.bound = 'sharp'`:
!> twomem_estimate_multiplier), with zero normal flux on the patch boundary
!> (except on ∂Ω at boundary vertices). Both membranes share the patch geometry, so each patch
!> is solved once with two right-hand sides: with its signature's factor and the operators of
!> its triangles' shape classes (twomem_estimate_shapes) where the hierarchy stores them, or on
!> the generic path, from the triangles' own geometry. Patches are independent: one OpenMP loop per vertex colour
!> (twomem_estimate_coloring), each patch adding its contribution to its own triangles, which no
!> other patch of the colour touches. On a single mesh the one-level algebraic flux's patches
!> (twomem_estimate_alg_single) have the same generic systems: given its source, the same pass
!> solves them too, from the same gathered operators and one factorization per patch.
module twomem_estimate_disc_flux
   use twomem_base_kinds, only: dp, ip
   use omp_lib, only: omp_get_thread_num
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, frame_of
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_patch_factor, only: solve_condensed_factored
   use twomem_estimate_patch_classes, only: patch_table_t, patch_signature_t, stored_order, max_patch
   use twomem_estimate_generic_patch, only: generic_scratch_t, factor_generic, solve_factored, patch_links
   use twomem_estimate_alg_single, only: algebraic_patch_data, algebraic_factored => factored_patch
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, gradients_on, lifting_on
   use twomem_estimate_multiplier, only: multiplier_weight
   implicit none
   private

   public :: discretization_flux, load_moments_t

   !> (f_α ψ_i, q_k)_K for every triangle, local vertex i and membrane: the data part of the
   !> patch right-hand sides, fixed on a mesh. Loads constant on Ω need nothing per triangle:
   !> f_α times the class integral of ψ_i q_k (twomem_estimate_shapes), which saves 18 values
   !> per triangle (a tenth of the estimators' memory).
   type :: load_moments_t
      logical :: constant = .false.
      real(dp) :: f(2) = 0.0_dp
      !> moments(:, i, t, α) when the loads are not constant
      real(dp), allocatable :: moments(:, :, :, :)
   contains
      procedure :: init => init_load_moments
   end type load_moments_t

contains

   !> The moments of data's loads on mesh (none stored when they are constant).
   subroutine init_load_moments(self, space, mesh, data)
      class(load_moments_t), intent(out) :: self
      type(rt_space_t), intent(in) :: space
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data

      call data%constant_loads(self%f, self%constant)
      if (self%constant) return
      allocate (self%moments(space%n_div, 3, mesh%nt, 2))
      call integrate_moments(space, mesh, data, self%moments)
   end subroutine init_load_moments

   !> The moments by the same degree-5 rule as the load vector, so that the patch data add up
   !> to exactly the F_α of the algebraic system.
   subroutine integrate_moments(space, mesh, data, moments)
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
         frame = frame_of(mesh%vertices, mesh%triangles(:, t))
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
   end subroutine integrate_moments

   !> (f_α ψ_i, q_k)_t for triangle t of class c at area factor ρ⁻² (i: local vertex).
   pure function moment(loads, shapes, i, t, c, area_factor, alpha) result(m)
      type(load_moments_t), intent(in) :: loads
      type(shape_classes_t), intent(in) :: shapes
      integer, intent(in) :: i, c, alpha
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: area_factor
      real(dp) :: m(size(shapes%psi_q, 1))

      if (loads%constant) then
         m = (loads%f(alpha)*area_factor)*shapes%psi_q(:, i, c)
      else
         m = loads%moments(:, i, t, alpha)
      end if
   end function moment

   !> sigma(:, t, α): coefficients of σ_α,disc on triangle t of `mesh`, level `level` of the
   !> hierarchy, whose vertex colouring is `colors`, for the evaluated iterate (its ∇u_α, λ_h and
   !> residual lifting); loads: the load moments. `table` holds the patch signatures of `mesh`'s
   !> vertices (twomem_estimate_patch_classes), whose patches use the signatures' factors and the
   !> operators of `shapes`; every other patch (all of them when the table holds none) takes the
   !> generic path (twomem_estimate_generic_patch) with the scratch of its thread (scratch(0:),
   !> one per thread). ok is .false. if some patch system is singular. With alg_source (the
   !> one-level Riesz representer, twomem_estimate_riesz) the same pass also returns the
   !> algebraic flux of twomem_estimate_alg_single in alg_sigma.
   subroutine discretization_flux(space, shapes, table, mesh, level, colors, mu, loads, iterate, scratch, sigma, ok, &
                                  alg_source, alg_sigma)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_table_t), intent(in) :: table
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level
      type(coloring_t), intent(in) :: colors
      real(dp), intent(in) :: mu(2)
      type(load_moments_t), intent(in) :: loads
      type(evaluated_iterate_t), intent(in) :: iterate
      type(generic_scratch_t), intent(inout) :: scratch(0:)
      real(dp), intent(inout) :: sigma(:, :, :)
      logical, intent(out) :: ok
      type(evaluated_iterate_t), intent(in), optional :: alg_source
      real(dp), intent(inout), optional :: alg_sigma(:, :, :)

      integer(ip) :: ib, m, a
      integer :: c, id, me, g
      logical :: patch_ok, signatures, with_alg
      integer(ip), allocatable :: generic(:)
      real(dp) :: none(0, 0, 0)

      ok = .true.
      signatures = allocated(table%levels)
      with_alg = present(alg_source) .and. present(alg_sigma)
      !$omp parallel default(none) &
      !$omp shared(space, shapes, table, mesh, level, colors, mu, loads, iterate, sigma, scratch) &
      !$omp shared(signatures, with_alg, alg_source, alg_sigma, none) &
      !$omp private(c, ib, m, a, id, patch_ok, me, g, generic) reduction(.and.:ok)
      me = omp_get_thread_num()
      !$omp workshare
      sigma = 0.0_dp
      !$omp end workshare
      if (with_alg) then
         !$omp workshare
         alg_sigma = 0.0_dp
         !$omp end workshare
      end if
      do c = 1, colors%n_colors
         !$omp do schedule(dynamic, 1)
         do ib = colors%ptr(c), colors%ptr(c + 1) - 1
            ! the block's patches without a signature: their triangles' operators, each once
            call generic_vertices(table, signatures, level, colors%vertices(colors%block_ptr(ib):colors%block_ptr(ib + 1) - 1), &
                                  generic)
            if (size(generic) > 0) then
               call scratch(me)%gather(space, mesh, generic, patch_ok)
               ok = ok .and. patch_ok
               if (.not. patch_ok) cycle
               call scratch(me)%fill(mesh, iterate, 1)
               if (with_alg) call scratch(me)%fill(mesh, alg_source, 2)
            end if
            g = 0
            do m = colors%block_ptr(ib), colors%block_ptr(ib + 1) - 1
               a = colors%vertices(m)
               id = 0
               if (signatures) id = table%levels(level)%id(a)
               if (id > 0) then
                  call factored_patch(space, shapes, table%sig(id), table%levels(level)%order(a), mesh, level, a, mu, &
                                      loads, iterate, sigma)
                  if (with_alg) call algebraic_factored(space, shapes, table, mesh, level, a, id, alg_source, .true., &
                                                        none, alg_sigma)
               else
                  g = g + 1
                  call generic_patch(space, scratch(me), g, mesh, a, mu, loads, iterate, with_alg, patch_ok)
                  ok = ok .and. patch_ok
               end if
            end do
            if (size(generic) > 0) then
               call scratch(me)%flush(sigma, 1)
               if (with_alg) call scratch(me)%flush(alg_sigma, 2)
            end if
         end do
         !$omp end do
      end do
      !$omp end parallel
   end subroutine discretization_flux

   !> The vertices of a block whose patches have no signature in `table`, in the block's order.
   pure subroutine generic_vertices(table, signatures, level, block, generic)
      type(patch_table_t), intent(in) :: table
      logical, intent(in) :: signatures
      integer, intent(in) :: level
      integer(ip), intent(in) :: block(:)
      integer(ip), allocatable, intent(inout) :: generic(:)

      integer :: m, n

      if (.not. signatures) then
         generic = block
         return
      end if
      n = count(table%levels(level)%id(block) == 0)
      if (allocated(generic)) deallocate (generic)
      allocate (generic(n))
      n = 0
      do m = 1, size(block)
         if (table%levels(level)%id(block(m)) /= 0) cycle
         n = n + 1
         generic(n) = block(m)
      end do
   end subroutine generic_vertices

   !> The patch of vertex a on the generic path: p is its position in the list the scratch was
   !> gathered for (generic_vertices), whose slots hold its triangles' operators and the
   !> iterate's ∇u_α and lifting there (data set 1). The data as in factored_patch, with the
   !> integrals of the triangle's own operators; σ goes to the slots' sums. With `with_alg`,
   !> the algebraic flux's patch too, from data set 2, on the same factorization.
   pure subroutine generic_patch(space, scratch, p, mesh, a, mu, loads, iterate, with_alg, ok)
      type(rt_space_t), intent(in) :: space
      type(generic_scratch_t), intent(inout) :: scratch
      integer, intent(in) :: p
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: a
      real(dp), intent(in) :: mu(2)
      type(load_moments_t), intent(in) :: loads
      type(evaluated_iterate_t), intent(in) :: iterate
      logical, intent(in) :: with_alg
      logical, intent(out) :: ok

      integer :: ne, k, i, alpha, s
      integer :: links(3, mesh%patch_ptr(a + 1) - mesh%patch_ptr(a)), corner(size(links, 2))
      real(dp) :: rhs_div(space%n_div, size(links, 2), 2), fgrad(2, size(links, 2), 2), lambda_a, d
      real(dp) :: none(0, 0, 0)
      real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]

      ne = size(links, 2)
      lambda_a = iterate%lambda(a)
      call patch_links(scratch, p, a, mesh%boundary_vertex(a), corner, links)
      associate (slots => scratch%slots(scratch%first(p):scratch%first(p + 1) - 1), ops => scratch%ops)
         do k = 1, ne
            s = slots(k)
            i = corner(k)
            do alpha = 1, 2
               associate (grad_u => scratch%grad(:, alpha, s, 1), r => scratch%lift(:, alpha, s, 1))
                  fgrad(:, k, alpha) = -mu(alpha)*grad_u
                  if (loads%constant) then
                     rhs_div(:, k, alpha) = loads%f(alpha)*ops%psi_q(:, i, s)
                  else
                     rhs_div(:, k, alpha) = loads%moments(:, i, scratch%triangles(s), alpha)
                  end if
                  d = mu(alpha)*(grad_u(1)*scratch%hat(1, i, s) + grad_u(2)*scratch%hat(2, i, s))
                  rhs_div(:, k, alpha) = rhs_div(:, k, alpha) + lambda_sign(alpha)*lambda_a* &
                                         multiplier_weight(iterate, mesh, a, scratch%triangles(s))* &
                                         ops%psi_q(:, i, s) &
                                         - ops%bary_psi_q(:, 1, i, s)*r(1) - ops%bary_psi_q(:, 2, i, s)*r(2) &
                                         - ops%bary_psi_q(:, 3, i, s)*r(3) - d*ops%q_int(:, s)
               end associate
            end do
         end do
         call factor_generic(space, scratch, slots, links, ok)
         if (.not. ok) return
         call solve_factored(space, scratch, slots, corner, links, fgrad, rhs_div, .true., 1)
         if (with_alg) then
            ! rhs_div's room for the algebraic flux's moments (fgrad is not read without a datum)
            call algebraic_patch_data(scratch, slots, corner, 2, .true., none, rhs_div)
            call solve_factored(space, scratch, slots, corner, links, fgrad, rhs_div, .false., 2)
         end if
      end associate
   end subroutine generic_patch

   !> The patch of vertex a with its signature's factor (twomem_estimate_patch_classes): the data
   !> of generic_patch in the signature's order of the triangles, with its classes' integrals.
   subroutine factored_patch(space, shapes, sig, order_code, mesh, level, a, mu, loads, iterate, sigma)
      type(rt_space_t), intent(in) :: space
      type(shape_classes_t), intent(in) :: shapes
      type(patch_signature_t), intent(in) :: sig
      !> the canonical order of the patch's triangles as its table stores it (stored_order)
      integer, intent(in) :: order_code
      type(mesh_t), intent(in) :: mesh
      integer, intent(in) :: level
      integer(ip), intent(in) :: a
      real(dp), intent(in) :: mu(2)
      type(load_moments_t), intent(in) :: loads
      type(evaluated_iterate_t), intent(in) :: iterate
      real(dp), intent(inout) :: sigma(:, :, :)

      ! fixed-size work arrays (sizes checked when the table was built): no allocation per patch
      integer :: k, i, alpha, c, ne, nd
      integer(ip) :: t, order(max_patch)
      real(dp) :: ratios(max_patch), area_factor
      real(dp) :: rhs_div(3, max_patch, 2), fgrad(2, max_patch, 2), grad_psi(2), hat_gradients(2, 3)
      real(dp) :: grad_u(2, 2), r(3, 2), lambda_a, weight
      real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]

      ne = size(sig%classes)
      lambda_a = iterate%lambda(a)
      nd = space%n_div
      call stored_order(shapes, mesh, level, a, order_code, order(1:ne))
      do k = 1, ne
         t = order(k)
         c = sig%classes(k)
         i = sig%corners(k)
         ratios(k) = shapes%ratio_of(level, t)
         area_factor = 1/ratios(k)**2
         hat_gradients = p1_gradients(mesh, t)
         grad_psi = hat_gradients(:, i)
         call gradients_on(iterate, mesh, t, hat_gradients, grad_u)
         call lifting_on(iterate, mesh, t, r)
         weight = multiplier_weight(iterate, mesh, a, t)
         do alpha = 1, 2
            fgrad(:, k, alpha) = -mu(alpha)*grad_u(:, alpha)
            rhs_div(1:nd, k, alpha) = moment(loads, shapes, i, t, c, area_factor, alpha) + area_factor*( &
                                      lambda_sign(alpha)*lambda_a*weight*shapes%psi_q(:, i, c) &
                                      - shapes%bary_psi_q(:, 1, i, c)*r(1, alpha) &
                                      - shapes%bary_psi_q(:, 2, i, c)*r(2, alpha) &
                                      - shapes%bary_psi_q(:, 3, i, c)*r(3, alpha) &
                                      - mu(alpha)*dot_product(grad_u(:, alpha), grad_psi)*shapes%q_int(:, c))
         end do
      end do
      call solve_condensed_factored(space, shapes, sig%classes, ratios(1:ne), sig%neumann, fgrad(:, 1:ne, :), &
                                    rhs_div(1:nd, 1:ne, :), .true., sig%factor, order(1:ne), sigma)
   end subroutine factored_patch
end module twomem_estimate_disc_flux
