!> The sharper variants of the guaranteed bound (estimate.bound, docs/method.md §3, *Sharper
!> bounds*): the exact root of the proof's last inequality and the triangles' Poincaré constant
!> ('root'), and the redistributed contact multiplier ('sharp'): its weights keep every lumped
!> patch mass, the discretization flux equilibrates it, and at the discrete solution of both
!> closed-form cases each variant still bounds the exact energy error, with a contact term that
!> matches its own integral here; the divergence-free correction of the flux ('sharp') keeps
!> every divergence moment and the normal continuity, lowers the flux term and solves its own
!> normal equations, both measured here by quadrature. Expected values are computed here, not
!> taken from the code under test.
module test_sharp_bounds
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: exact_radial, exact_bbbv, domain_disk, bound_paper, bound_root, bound_sharp
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_error, only: energy_error_per_element
   use twomem_newton_solver, only: newton_result_t
   use twomem_linalg_halo, only: halo_t
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, make_frame
   use twomem_estimate_disc_flux, only: discretization_flux, load_moments_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_alg_flux, only: level_flux_t
   use twomem_estimate_patch_classes, only: patch_table_t
   use twomem_estimate_generic_patch, only: generic_scratch_t
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_estimate_multiplier, only: multiplier_factors
   use twomem_estimate_flux_correction, only: correct_flux
   use twomem_fem_assembly, only: p1_gradients
   use twomem_estimate_estimators, only: estimator_t, estimates_t, poincare_constant
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_estimate, only: solved_disk, random_vector, mesh_problem, poly_data_t, path_fixtures, iterate_fields, &
                            check_normal_continuity
   implicit none
   private

   public :: collect_sharp_bounds

   real(dp), parameter :: pi = acos(-1.0_dp), j11 = 3.831705970207512_dp
   real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]
   !> the moved fraction θ of twomem_estimate_multiplier
   real(dp), parameter :: theta = 0.5_dp

contains

   subroutine collect_sharp_bounds(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('root_and_triangle_constant', test_root), &
               new_unittest('multiplier_masses_and_equilibrium', test_multiplier), &
               new_unittest('bounds_at_discrete_solution', test_at_solution), &
               new_unittest('divergence_free_flux_correction', test_correction)]
   end subroutine collect_sharp_bounds

   !> The test's own weights w_a on triangle t: u1 ≤ u2 at its three vertices (up to the code's
   !> round-off allowance) decides contact; a vertex with λ(a) > 0 whose patch has triangles of
   !> both kinds moves θ of its mass onto the contact ones.
   subroutine own_weights(mesh, u, lambda, w)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :), lambda(:)
      !> w(k, t): the weight of the k-th vertex of t on t
      real(dp), allocatable, intent(out) :: w(:, :)

      logical, allocatable :: contact(:)
      real(dp) :: whole, touching
      integer(ip) :: t, a, m
      integer :: k

      allocate (contact(mesh%nt), w(3, mesh%nt))
      do t = 1, mesh%nt
         contact(t) = all(u(mesh%triangles(:, t), 1) - u(mesh%triangles(:, t), 2) <= &
                          1.0e-10_dp*(abs(u(mesh%triangles(:, t), 1)) + abs(u(mesh%triangles(:, t), 2))))
      end do
      w = 1.0_dp
      do t = 1, mesh%nt
         do k = 1, 3
            a = mesh%triangles(k, t)
            if (lambda(a) <= 0.0_dp .or. mesh%boundary_vertex(a)) cycle
            whole = 0.0_dp
            touching = 0.0_dp
            do m = mesh%patch_ptr(a), mesh%patch_ptr(a + 1) - 1
               whole = whole + mesh%area(mesh%patch_triangles(m))
               if (contact(mesh%patch_triangles(m))) touching = touching + mesh%area(mesh%patch_triangles(m))
            end do
            if (touching == 0.0_dp .or. touching == whole) cycle
            w(k, t) = merge(1 + theta*(whole/touching - 1), 1 - theta, contact(t))
         end do
      end do
   end subroutine own_weights

   !> At a random nonconforming iterate with a load outside P1 (nonzero oscillation, λ_h of both
   !> signs, u1 < u2 in places): with 'root' the oscillation is the paper's times π/j_{1,1}, the
   !> bound is the root A/2 + (A²/4 + c/2)^½ of its own parts, and it is below the paper's
   !> (A² + c)^½ of the same parts, and below the paper's bound.
   subroutine test_root(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(estimator_t) :: paper, root
      type(estimates_t) :: ep, er
      real(dp), allocatable :: x(:)
      real(dp) :: a, c

      data%c = [2.0_dp, -1.5_dp]
      call mesh_problem('disk', 0.5_dp, 1, data, h, p, err)
      if (allocated(err)) return
      x = random_vector(3*p%n, 41)
      call paper%init(h, data, 1, 2, poincare_constant(domain_disk, 2.0_dp), err)
      if (allocated(err)) return
      call root%init(h, data, 1, 2, poincare_constant(domain_disk, 2.0_dp), err, bound=bound_root)
      if (allocated(err)) return
      call paper%evaluate(h, data, p, x, ep, err)
      if (allocated(err)) return
      call root%evaluate(h, data, p, x, er, err)
      if (allocated(err)) return
      call check(err, ep%osc > 0.0_dp .and. ep%nonc1 > 0.0_dp .and. ep%nonc2 > 0.0_dp, 'a nonconforming iterate')
      call check_close(err, er%osc, ep%osc*pi/j11, 1.0e-12_dp, 0.0_dp, 'oscillation with h_K/j11')
      call check_close(err, er%flux, ep%flux, 1.0e-13_dp, 0.0_dp, 'same fluxes')
      call check_close(err, er%contact, ep%contact, 1.0e-13_dp, 0.0_dp, 'same contact term')
      a = er%eta_1 + er%alg_remainder + er%nonc1 + er%nonc2
      c = er%nonc3 + er%contact
      call check_close(err, er%total, a/2 + sqrt(a**2/4 + c/2), 1.0e-13_dp, 0.0_dp, 'exact root')
      call check(err, er%total <= sqrt(a**2 + c), 'root below the paper''s combination of the same parts')
      call check(err, er%total < ep%total, 'root bound below the paper''s bound')
      a = ep%eta_1 + ep%alg_remainder + ep%nonc1 + ep%nonc2
      c = ep%nonc3 + ep%contact
      call check_close(err, ep%total, sqrt(a**2 + c), 1.0e-13_dp, 0.0_dp, 'the paper''s (41)')
   end subroutine test_root

   !> A random iterate on a disk: the test's own weights keep every interior vertex's lumped mass
   !> (Σ_K w_a |K|/3 = |ω_a|/3, w ≥ 0) and some move; the code's factors give the same weights;
   !> σ_disc built with them has on every triangle the divergence moments of f_α ∓ λ̃ − r_α with
   !> λ̃ = Σ_a λ_h(a) w_a ψ_a, and continuous normal components (RT0 and RT1).
   subroutine test_multiplier(err)
      type(error_t), allocatable, intent(out) :: err
      type(generic_scratch_t), allocatable :: scratch(:)
      type(halo_t) :: halo
      type(ghost_cells_t) :: ghosts
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(level_flux_t) :: levels(1)
      type(rt_frame_t) :: frame
      type(load_moments_t) :: loads
      type(evaluated_iterate_t) :: iterate
      real(dp), allocatable :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :), lhs(:), rhs(:), w(:, :)
      real(dp), allocatable :: mass(:), x(:)
      real(dp) :: pt(2), wq, dev, scale, lam_t(3)
      integer(ip) :: t, v(3), n
      integer :: order, alpha, k, moved

      call mesh_problem('disk', 0.3_dp, 0, data, h, p, err)
      if (allocated(err)) return
      call path_fixtures(h, p, scratch, halo, ghosts)
      n = p%n
      ! gaps of both signs, half of them in contact (u2 = u1 there), λ mostly positive
      x = random_vector(3*n, 77)
      x(n + 1:2*n) = x(1:n) - merge(0.0_dp, abs(x(n + 1:2*n)), x(n + 1:2*n) < 0.0_dp)
      x(2*n + 1:) = x(2*n + 1:) + 0.3_dp
      call iterate_fields(p, h%meshes(0), x, lambda, grad_u, residual, r, iterate)
      associate (mesh => h%meshes(0))
         call own_weights(mesh, iterate%u, lambda, w)
         moved = count(w /= 1.0_dp)
         call check(err, moved > 0 .and. all(w >= 0.0_dp), 'weights nonnegative, some mass moves')
         allocate (mass(mesh%nv))
         mass = 0.0_dp
         do t = 1, mesh%nt
            do k = 1, 3
               mass(mesh%triangles(k, t)) = mass(mesh%triangles(k, t)) + (w(k, t) - 1)*mesh%area(t)/3
            end do
         end do
         call check(err, maxval(abs(mass)) <= 1.0e-14_dp*maxval(mesh%area), 'lumped patch masses kept')
         call multiplier_factors(mesh, iterate)
         do order = 0, 1
            call disc_flux_on_disk(order, h, data, p, iterate, scratch, space, loads, levels(1)%sigma, err)
            if (allocated(err)) return
            if (allocated(lhs)) deallocate (lhs, rhs)
            allocate (lhs(space%n_div), rhs(space%n_div))
            dev = 0.0_dp
            scale = 0.0_dp
            do t = 1, mesh%nt
               v = mesh%triangles(:, t)
               frame = make_frame(mesh%vertices(:, v))
               lam_t = lambda(v)*w(:, t)
               do alpha = 1, 2
                  lhs = 0.0_dp
                  rhs = sum(loads%moments(:, :, t, alpha), dim=2)
                  do k = 1, space%rule%n
                     pt = matmul(mesh%vertices(:, v), space%rule%bary(:, k))
                     wq = space%rule%weights(k)*mesh%area(t)
                     lhs = lhs + wq*dot_product(space%divergence_values(frame, pt), levels(1)%sigma(:, t, alpha)) &
                           *space%div_test_values(frame, pt)
                     rhs = rhs + wq*(lambda_sign(alpha)*dot_product(lam_t, space%rule%bary(:, k)) &
                                     - dot_product(r(:, t, alpha), space%rule%bary(:, k)))*space%div_test_values(frame, pt)
                  end do
                  dev = max(dev, maxval(abs(lhs - rhs)))
                  scale = max(scale, maxval(abs(rhs)), norm2(grad_u(:, t, alpha))*mesh%area(t)/mesh%diameter_of(t))
               end do
            end do
            call check(err, dev <= 1.0e-12_dp*scale, 'sigma_disc equilibrates the moved multiplier')
            levels(1)%level = 0
            call check_normal_continuity(err, space, h, levels, 1.0e-12_dp, 'sigma_disc, moved multiplier')
         end do
      end associate
   end subroutine test_multiplier

   !> At the exact Newton-min solution of both closed-form cases, RT0 and RT1: every variant
   !> bounds the exact energy error; 'root' is below 'paper'; with 'sharp' the contact term is
   !> 2 Σ_K (λ̃, u1h − u2h)_K of the test's own weights (λ̃ ≥ 0 there: no clipping), below the
   !> paper's, and the nonconformity terms still vanish.
   subroutine test_at_solution(err)
      type(error_t), allocatable, intent(out) :: err
      character(len=6), parameter :: cases(2) = ['radial', 'bbbv  ']
      integer, parameter :: kinds(2) = [exact_radial, exact_bbbv], bounds(3) = [bound_paper, bound_root, bound_sharp]
      type(mesh_hierarchy_t) :: h
      class(problem_data_t), allocatable :: data
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res
      type(estimator_t) :: estimator
      type(estimates_t) :: est(3)
      real(dp), allocatable :: u(:, :), lambda(:), w(:, :)
      real(dp) :: energy, contact, lv(3), gv(3)
      integer(ip) :: t, v(3)
      integer :: c, order, b
      character(len=24) :: what

      do c = 1, 2
         call solved_disk(kinds(c), data, h, p, res, err)
         if (allocated(err)) return
         associate (mesh => h%meshes(2))
            u = reshape([p%to_nodal(res%x(1:p%n), p%g), p%to_nodal(res%x(p%n + 1:2*p%n), 0.0_dp)], [mesh%nv, 2])
            lambda = p%to_nodal(res%x(2*p%n + 1:), 0.0_dp)
            energy = norm2(energy_error_per_element(mesh, data, u(:, 1), u(:, 2)))
            call own_weights(mesh, u, lambda, w)
            call check(err, count(w /= 1.0_dp) > 0, 'mass moves at the free boundary: '//trim(cases(c)))
            contact = 0.0_dp
            do t = 1, mesh%nt
               v = mesh%triangles(:, t)
               lv = max(0.0_dp, lambda(v))*w(:, t)
               gv = u(v, 1) - u(v, 2)
               contact = contact + 2*mesh%area(t)/12*(dot_product(lv, gv) + sum(lv)*sum(gv))
            end do
            call check(err, all(lambda >= 0.0_dp), 'lambda_h >= 0 at the solution: '//trim(cases(c)))
            do order = 0, 1
               do b = 1, 3
                  write (what, '(a," RT",i0," bound ",i0)') trim(cases(c)), order, bounds(b)
                  call estimator%init(h, data, order, 3, poincare_constant(domain_disk, 2.0_dp), err, bound=bounds(b))
                  if (allocated(err)) return
                  call estimator%evaluate(h, data, p, res%x, est(b), err)
                  if (allocated(err)) return
                  call check(err, est(b)%total >= energy, 'eta_total >= energy error: '//what)
                  call check(err, est(b)%lin <= 1.0e-10_dp*est(b)%disc, 'eta_lin = 0 at the solution: '//what)
               end do
               call check(err, est(2)%total <= est(1)%total, 'root <= paper: '//what)
               call check_close(err, est(3)%contact, contact, 1.0e-10_dp, 1.0e-14_dp*est(1)%contact, &
                                'contact term of the moved multiplier: '//what)
               call check(err, est(3)%contact < 0.75_dp*est(1)%contact, 'contact term shrinks: '//what)
            end do
         end associate
      end do
   end subroutine test_at_solution
   !> A random iterate on a disk, RT0 and RT1: the corrected σ_disc has the divergence moments of
   !> the uncorrected one on every triangle and continuous normal components; its flux term
   !> Σ_K ‖μ_α^{−½}(μ_α∇u_αh + σ_α)‖²_K, by quadrature, is lower; and the gradient of that term
   !> with respect to φ_α, (μ_α∇u_αh + σ_α, curl ψ_i) at every interior vertex i, has shrunk
   !> to the conjugate gradients' relative tolerance (10⁻²) when they may run to it: the
   !> correction is the minimizer. With the run's iteration cap (5 for RT1) the flux term falls
   !> too.
   subroutine test_correction(err)
      type(error_t), allocatable, intent(out) :: err
      type(generic_scratch_t), allocatable :: scratch(:)
      type(halo_t) :: halo
      type(ghost_cells_t) :: ghosts
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(level_flux_t) :: levels(1)
      type(rt_frame_t) :: frame
      type(load_moments_t) :: loads
      type(evaluated_iterate_t) :: iterate
      real(dp), allocatable :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :), x(:), sigma0(:, :, :)
      real(dp), allocatable :: gradient(:, :, :), capped(:, :, :)
      real(dp) :: pt(2), wq, mu(2), field(2, 2), div(2), dev, scale, flux(2), hat(2, 3), curl(2), capped_flux
      integer(ip) :: t, v(3), n, i
      integer :: order, alpha, k, m, iterations(2), c

      call mesh_problem('disk', 0.2_dp, 0, data, h, p, err)
      if (allocated(err)) return
      call path_fixtures(h, p, scratch, halo, ghosts)
      n = p%n
      mu = [p%mu1, p%mu2]
      x = random_vector(3*n, 91)
      x(2*n + 1:) = x(2*n + 1:) + 0.3_dp
      call iterate_fields(p, h%meshes(0), x, lambda, grad_u, residual, r, iterate)
      associate (mesh => h%meshes(0))
         call multiplier_factors(mesh, iterate)
         do order = 0, 1
            call disc_flux_on_disk(order, h, data, p, iterate, scratch, space, loads, levels(1)%sigma, err)
            if (allocated(err)) return
            sigma0 = levels(1)%sigma
            ! the run's own cap first (the flux term must fall), then to the tolerance
            call correct_flux(order, mesh, p, halo, levels(1)%sigma, iterations, err)
            if (allocated(err)) return
            call check(err, all(iterations >= 1), 'the correction iterates')
            capped = levels(1)%sigma
            levels(1)%sigma = sigma0
            call correct_flux(order, mesh, p, halo, levels(1)%sigma, iterations, err, max_iterations=1000)
            if (allocated(err)) return
            ! per triangle and membrane, before (c = 1) and after (c = 2): the flux term, the
            ! divergence's deviation at the quadrature points, and (μ∇u + σ, curl ψ_i)
            allocate (gradient(mesh%nv, 2, 2))
            gradient = 0.0_dp
            flux = 0.0_dp
            capped_flux = 0.0_dp
            dev = 0.0_dp
            scale = 0.0_dp
            do t = 1, mesh%nt
               v = mesh%triangles(:, t)
               frame = make_frame(mesh%vertices(:, v))
               hat = p1_gradients(mesh, t)
               do k = 1, space%rule%n
                  pt = matmul(mesh%vertices(:, v), space%rule%bary(:, k))
                  wq = space%rule%weights(k)*mesh%area(t)
                  do alpha = 1, 2
                     capped_flux = capped_flux + wq*sum((mu(alpha)*grad_u(:, t, alpha) + &
                                   matmul(space%flux_values(frame, pt), capped(:, t, alpha)))**2)/mu(alpha)
                     field(:, 1) = mu(alpha)*grad_u(:, t, alpha) + matmul(space%flux_values(frame, pt), sigma0(:, t, alpha))
                     field(:, 2) = mu(alpha)*grad_u(:, t, alpha) + &
                                   matmul(space%flux_values(frame, pt), levels(1)%sigma(:, t, alpha))
                     div(1) = dot_product(space%divergence_values(frame, pt), sigma0(:, t, alpha))
                     div(2) = dot_product(space%divergence_values(frame, pt), levels(1)%sigma(:, t, alpha))
                     dev = max(dev, abs(div(2) - div(1)))
                     scale = max(scale, abs(div(1)))
                     do c = 1, 2
                        flux(c) = flux(c) + wq*sum(field(:, c)**2)/mu(alpha)
                        do m = 1, 3
                           curl = [hat(2, m), -hat(1, m)]
                           gradient(v(m), alpha, c) = gradient(v(m), alpha, c) + wq*dot_product(field(:, c), curl)
                        end do
                     end do
                  end do
               end do
            end do
            call check(err, dev <= 1.0e-12_dp*scale, 'divergence unchanged by the correction')
            call check(err, flux(2) < flux(1), 'the correction lowers the flux term')
            call check(err, capped_flux < flux(1), 'the run''s capped correction lowers the flux term')
            do alpha = 1, 2
               do c = 1, 2
                  do i = 1, mesh%nv
                     if (p%unknown(i) == 0) gradient(i, alpha, c) = 0.0_dp
                  end do
               end do
               call check(err, norm2(gradient(:, alpha, 2)) <= 1.0e-2_dp*norm2(gradient(:, alpha, 1)), &
                          'the corrected flux solves its normal equations')
            end do
            levels(1)%level = 0
            call check_normal_continuity(err, space, h, levels, 1.0e-12_dp, 'corrected sigma_disc')
            deallocate (gradient)
         end do
      end associate
   end subroutine test_correction
   !> σ_disc of `iterate` on h's mesh (level 0, no stored patch tables: the generic path) in
   !> RT_order, with the space and load moments it was built from; err if a patch system is
   !> singular.
   subroutine disc_flux_on_disk(order, h, data, p, iterate, scratch, space, loads, sigma, err)
      integer, intent(in) :: order
      type(mesh_hierarchy_t), intent(in) :: h
      type(poly_data_t), intent(in) :: data
      type(discrete_problem_t), intent(in) :: p
      type(evaluated_iterate_t), intent(in) :: iterate
      type(generic_scratch_t), intent(inout) :: scratch(0:)
      type(rt_space_t), intent(out) :: space
      type(load_moments_t), intent(out) :: loads
      real(dp), allocatable, intent(out) :: sigma(:, :, :)
      type(error_t), allocatable, intent(out) :: err

      type(shape_classes_t) :: shapes
      type(coloring_t) :: colors
      type(patch_table_t) :: no_signatures
      logical :: ok

      call space%init(order)
      call shapes%init(space, h, err)
      if (allocated(err)) return
      call colors%init(h%meshes(0))
      allocate (sigma(space%n_flux, h%meshes(0)%nt, 2))
      call loads%init(space, h%meshes(0), data)
      call discretization_flux(space, shapes, no_signatures, h%meshes(0), 0, colors, [p%mu1, p%mu2], loads, iterate, &
                               scratch, sigma, ok)
      call check(err, ok, 'patch systems regular')
   end subroutine disc_flux_on_disk
end module test_sharp_bounds
