!> The a posteriori estimators' building blocks (src/fortran/estimate): the Raviart–Thomas
!> element against Green's formula, the residual lifting against the P1 mass matrix, equilibrium
!> and normal continuity of both flux reconstructions; and the fixtures the estimator suites
!> share (the patch loops' tests are test_patch_loops'). The estimators' values are test_estimator_values'. Expected values are
!> computed here (exact P1/barycentric integrals), not taken from the code under test.
module test_estimate
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: method_direct
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_generators, only: make_disk, make_square
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t, parent_triangle
   use twomem_fem_problem, only: problem_data_t, constant_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_fem_cases, only: make_problem
   use twomem_linalg_dense, only: cholesky_factor, lu_factor, lu_solve
   use twomem_newton_solver, only: newton_options_t, newton_result_t, newton_solve
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, make_frame, edge_gauss
   use twomem_estimate_lifting, only: algebraic_residuals
   use twomem_estimate_disc_flux, only: discretization_flux, load_moments_t
   use twomem_estimate_evaluated_iterate, only: evaluated_iterate_t, gradients_on, lifting_on
   use twomem_estimate_shapes, only: shape_classes_t
   use twomem_estimate_coloring, only: coloring_t
   use twomem_estimate_alg_flux, only: algebraic_flux_t, level_flux_t
   use twomem_estimate_patch_classes, only: patch_table_t
   use twomem_estimate_generic_patch, only: generic_scratch_t
   use twomem_estimate_ghosts, only: ghost_cells_t
   use twomem_linalg_halo, only: halo_t
   use twomem_base_comm, only: comm_t
   use omp_lib, only: omp_get_max_threads
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_estimate, solved_disk, random_vector, mesh_problem, poly_data_t, lifting_by_local_solves, &
             path_fixtures, iterate_fields, check_normal_continuity

   !> λ enters the first membrane's equilibrium with +, the second's with −
   real(dp), parameter :: lambda_sign(2) = [1.0_dp, -1.0_dp]

   !> μ1 = 1, μ2 = 2 and loads f_α = a_α + b_α·x + c_α x1 x2: linear loads have moments exact by
   !> barycentric formulas, the x1 x2 term an exactly computable P1 oscillation.
   type, extends(problem_data_t) :: poly_data_t
      real(dp) :: a(2) = [-1.0_dp, 3.0_dp], b(2, 2) = reshape([0.5_dp, -0.25_dp, 1.0_dp, 0.75_dp], [2, 2])
      real(dp) :: c(2) = 0.0_dp
   contains
      procedure :: load => poly_load
   end type poly_data_t

contains

   subroutine collect_estimate(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('rt_green_formula', test_rt_green), &
               new_unittest('rt_mass_and_orientation', test_rt_mass), &
               new_unittest('residual_and_lifting', test_lifting), &
               new_unittest('disc_flux_equilibrium_continuity', test_disc_flux), &
               new_unittest('alg_flux_divergence_continuity', test_alg_flux)]
   end subroutine collect_estimate

   !> Green's formula per basis function, (∇·φ_i, q) + (φ_i, ∇q) = ⟨φ_i·n, q⟩_∂K, for q = 1 and
   !> (RT1) q = ξ1, ξ2, whose edge traces are written in the trace basis {1, t}: it ties the
   !> divergence, the mass matrix ((φ_i, ∇ξ_k) = (φ_i, φ_k)/h_K) and both trace moments together.
   subroutine test_rt_green(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), parameter :: v(2, 3) = reshape([0.1_dp, -0.2_dp, 1.3_dp, 0.1_dp, 0.4_dp, 0.9_dp], [2, 3])
      type(rt_space_t) :: space
      real(dp), allocatable :: mass(:, :), div(:, :), trace(:, :, :)
      real(dp) :: h, xi(2, 3), rhs, scale
      integer :: order, i, k, m, s, e

      h = max(norm2(v(:, 2) - v(:, 1)), norm2(v(:, 3) - v(:, 2)), norm2(v(:, 1) - v(:, 3)))
      xi = (v - spread(sum(v, dim=2)/3, 2, 3))/h
      do order = 0, 1
         call space%init(order)
         allocate (mass(space%n_flux, space%n_flux), div(space%n_div, space%n_flux), trace(space%n_trace, space%n_flux, 3))
         call space%element_matrices(make_frame(v), [.true., .true., .true.], mass, div, trace)
         scale = maxval(abs(trace))
         do i = 1, space%n_flux
            call check_close(err, div(1, i), sum(trace(1, i, :)), 0.0_dp, 1.0e-14_dp*scale, 'divergence theorem')
            do k = 1, 2*order
               rhs = 0.0_dp
               do m = 1, 3
                  s = modulo(m, 3) + 1 ! forward: t runs from local vertex m+1 (t = −1) to m+2 (t = 1)
                  e = modulo(m + 1, 3) + 1
                  rhs = rhs + 0.5_dp*(xi(k, s) + xi(k, e))*trace(1, i, m) + 0.5_dp*(xi(k, e) - xi(k, s))*trace(2, i, m)
               end do
               call check_close(err, div(1 + k, i) + mass(k, i)/h, rhs, 0.0_dp, 1.0e-14_dp*scale, 'Green with q = xi_k')
            end do
         end do
         deallocate (mass, div, trace)
      end do
   end subroutine test_rt_green

   !> The mass matrix is symmetric positive definite, with the exact moments (1, 1) = |K|,
   !> (1, 2) = 0, (1, ξ1) = 0 (barycentre) and, for RT0, ∫|ξ|² = |K|/12 Σ_i |ξ(v_i)|². Reversing
   !> an edge flips the sign of its t-moment (not identically zero, else the flip would be
   !> invisible) and leaves its mean alone.
   subroutine test_rt_mass(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp), parameter :: v(2, 3) = reshape([2.0_dp, 1.0_dp, 2.3_dp, 1.05_dp, 2.1_dp, 1.4_dp], [2, 3])
      type(rt_space_t) :: space
      real(dp), allocatable :: mass(:, :), div(:, :), trace(:, :, :)
      real(dp) :: area, h, xi2, tr_fwd(2, 8, 3)
      integer :: order, m
      logical :: ok

      area = 0.5_dp*abs((v(1, 2) - v(1, 1))*(v(2, 3) - v(2, 1)) - (v(1, 3) - v(1, 1))*(v(2, 2) - v(2, 1)))
      h = max(norm2(v(:, 2) - v(:, 1)), norm2(v(:, 3) - v(:, 2)), norm2(v(:, 1) - v(:, 3)))
      xi2 = sum((v - spread(sum(v, dim=2)/3, 2, 3))**2)/h**2
      do order = 0, 1
         call space%init(order)
         allocate (mass(space%n_flux, space%n_flux), div(space%n_div, space%n_flux), trace(space%n_trace, space%n_flux, 3))
         call space%element_matrices(make_frame(v), [.false., .true., .false.], mass, div, trace)
         call check(err, maxval(abs(mass - transpose(mass))) <= 1.0e-15_dp*maxval(abs(mass)), 'mass symmetric')
         call check_close(err, mass(1, 1), area, 1.0e-14_dp, 0.0_dp, '(phi_1, phi_1) = |K|')
         call check_close(err, mass(1, 2), 0.0_dp, 0.0_dp, 1.0e-15_dp*area, '(phi_1, phi_2) = 0')
         call check_close(err, mass(1, 3), 0.0_dp, 0.0_dp, 1.0e-15_dp*area, 'first moment about the barycentre')
         if (order == 0) call check_close(err, mass(3, 3), area/12*xi2, 1.0e-14_dp, 0.0_dp, '(xi, xi)')
         if (order == 1) then
            call space%element_matrices(make_frame(v), [.true., .true., .true.], mass, div, tr_fwd)
            call check(err, all(trace(1, :, :) == tr_fwd(1, :, :)), 'mean moment independent of orientation')
            do m = 1, 3
               call check(err, maxval(abs(tr_fwd(2, :, m))) > 1.0e-2_dp*area, 't-moment not identically zero')
               call check(err, all(trace(2, :, m) == merge(1, -1, m == 2)*tr_fwd(2, :, m)), 't-moment sign follows forward')
            end do
         end if
         call cholesky_factor(mass, ok)
         call check(err, ok, 'mass positive definite')
         deallocate (mass, div, trace)
      end do
   end subroutine test_rt_mass

   !> algebraic_residuals is F_1 − μ1 S X1 + D X3 and F_2 − μ2 S X2 − D X3 at the interior
   !> vertices (S X and D = |ω_a|/3 assembled here triangle by triangle) and zero elsewhere; the
   !> lifting satisfies (r, ψ_a) = R(a) at interior vertices (exact P1 mass matrix
   !> |K|/12 (1 + δ_ij)) and vanishes at boundary vertices.
   subroutine test_lifting(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      real(dp), allocatable :: x(:), work(:), r1(:), r2(:), sx(:, :), d(:), u(:, :), expected(:), r(:, :, :), moment(:), &
                               nodal(:, :)
      logical, allocatable :: off_unknowns(:)
      type(evaluated_iterate_t) :: iterate
      integer(ip) :: n, t, v(3), i
      integer :: alpha

      call mesh_problem('disk', 0.5_dp, 1, data, h, p, err)
      if (allocated(err)) return
      n = p%n
      x = random_vector(3*n, 11)
      associate (mesh => h%meshes(1))
         ! (filled first: the zeros off the unknowns must be written, not found)
         allocate (nodal(mesh%nv, 2), source=1.0_dp)
         allocate (work(n))
         call algebraic_residuals(p, x, nodal, work)
         r1 = nodal(p%interior, 1)
         r2 = nodal(p%interior, 2)
         allocate (sx(mesh%nv, 2), d(mesh%nv), u(mesh%nv, 2), r(3, mesh%nt, 2), moment(mesh%nv))
         u = reshape([p%to_nodal(x(1:n), 0.0_dp), p%to_nodal(x(n + 1:2*n), 0.0_dp)], [mesh%nv, 2])
         sx = 0.0_dp
         d = 0.0_dp
         do t = 1, mesh%nt
            v = mesh%triangles(:, t)
            do alpha = 1, 2
               sx(v, alpha) = sx(v, alpha) + mesh%area(t)*matmul(transpose(p1_gradients(mesh, t)), &
                                                                 matmul(p1_gradients(mesh, t), u(v, alpha)))
            end do
            d(v) = d(v) + mesh%area(t)/3
         end do
         expected = p%f(1:n) - p%mu1*sx(p%interior, 1) + d(p%interior)*x(2*n + 1:)
         call check(err, maxval(abs(r1 - expected)) <= 1.0e-13_dp*maxval(abs(expected)), 'R_1')
         expected = p%f(n + 1:) - p%mu2*sx(p%interior, 2) - d(p%interior)*x(2*n + 1:)
         call check(err, maxval(abs(r2 - expected)) <= 1.0e-13_dp*maxval(abs(expected)), 'R_2')
         off_unknowns = p%unknown == 0
         call check(err, all(pack(nodal(:, 1), off_unknowns) == 0.0_dp) .and. &
                    all(pack(nodal(:, 2), off_unknowns) == 0.0_dp), 'R_α is zero at the vertices of no unknown')

         ! the lifting as the fluxes read it, triangle by triangle
         call iterate%init(mesh)
         iterate%shares = nodal
         call iterate%set_shares(mesh)
         do t = 1, mesh%nt
            call lifting_on(iterate, mesh, t, r(:, t, :))
         end do
         moment = 0.0_dp
         do t = 1, mesh%nt
            v = mesh%triangles(:, t)
            moment(v) = moment(v) + mesh%area(t)/12*(r(:, t, 1) + sum(r(:, t, 1)))
            do i = 1, 3
               if (mesh%boundary_vertex(v(i))) call check(err, all(r(i, t, :) == 0.0_dp), 'r = 0 at boundary vertices')
            end do
         end do
         call check(err, maxval(abs(moment(p%interior) - r1)) <= 1.0e-12_dp*maxval(abs(r1)), '(r, psi_a) = R(a)')
      end associate
   end subroutine test_lifting

   !> σ_disc for a random iterate and linear loads, RT0 and RT1, on a disk and on a 7×7 square
   !> (whose corner triangles have three boundary vertices): the load moments are the exact
   !> (f ψ_i, q_k)_K, on every triangle the moments of ∇·σ_α against P_p are those of
   !> f_α ± λ_h − r_α, and σ·n is continuous across interior edges. Constant loads, whose
   !> moments come from the class integrals, give the σ_disc of the same loads integrated per
   !> triangle.
   subroutine test_disc_flux(err)
      type(error_t), allocatable, intent(out) :: err
      !> the generic path's per-thread scratch, the one-rank halo and ghost layer
      type(generic_scratch_t), allocatable :: scratch(:)
      type(halo_t) :: halo
      type(ghost_cells_t) :: ghosts
      character(len=6), parameter :: domains(2) = ['disk  ', 'square']
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(shape_classes_t) :: shapes
      type(coloring_t) :: colors
      type(level_flux_t) :: levels(1)
      !> no signatures: the general path of every patch is what this test checks
      type(patch_table_t) :: no_signatures
      type(rt_frame_t) :: frame
      type(load_moments_t) :: loads, flat_loads
      type(poly_data_t) :: flat_poly
      type(constant_data_t) :: flat
      type(evaluated_iterate_t) :: iterate
      real(dp), allocatable :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :), lhs(:), rhs(:)
      real(dp), allocatable :: flat_sigma(:, :, :)
      real(dp) :: x(2), w, dev, scale, q(3, 3), fv(3), exact, tri(3, 3, 3), mu(2), g_on(2, 2), r_on(3, 2)
      integer(ip) :: t, v(3)
      integer :: domain, order, alpha, k, i, j, l
      logical :: ok

      ! ∫ λ_i λ_j λ_l = |K|/60 (1 + δ_ij + δ_il + δ_jl + 2 δ_ijl)
      tri = reshape([(((real(1 + merge(1, 0, i == j) + merge(1, 0, i == l) + merge(1, 0, j == l) + &
                            merge(2, 0, i == j .and. j == l), dp)/60, i=1, 3), j=1, 3), l=1, 3)], [3, 3, 3])
      do domain = 1, 2
         call mesh_problem(trim(domains(domain)), merge(0.4_dp, 0.3_dp, domain == 1), 0, data, h, p, err)
         if (allocated(err)) return
         call path_fixtures(h, p, scratch, halo, ghosts)
         call iterate_fields(p, h%meshes(0), random_vector(3*p%n, 20 + domain), lambda, grad_u, residual, r, iterate)
         mu = [p%mu1, p%mu2]
         associate (mesh => h%meshes(0))
            ! the fluxes read ∇u_α and r_α triangle by triangle, computed where they are read: the
            ! gradients with the expression of the whole-mesh loop (exactly), the lifting as the
            ! local mass solves of iterate_fields give it (to round-off)
            dev = 0.0_dp
            scale = 0.0_dp
            do t = 1, mesh%nt
               call gradients_on(iterate, mesh, t, p1_gradients(mesh, t), g_on)
               call check(err, all(g_on == grad_u(:, t, :)), 'gradients_on is the whole-mesh gradient')
               call lifting_on(iterate, mesh, t, r_on)
               dev = max(dev, maxval(abs(r_on - r(:, t, :))))
               scale = max(scale, maxval(abs(r(:, t, :))))
            end do
            call check(err, dev <= 1.0e-13_dp*scale, 'lifting_on is the lifting of the local mass solves')
            do order = 0, 1
               call space%init(order)
               call shapes%init(space, h, err)
               if (allocated(err)) return
               call colors%init(mesh)
               if (allocated(lhs)) deallocate (lhs, rhs, levels(1)%sigma, flat_sigma)
               allocate (lhs(space%n_div), rhs(space%n_div), levels(1)%sigma(space%n_flux, mesh%nt, 2), &
                         flat_sigma(space%n_flux, mesh%nt, 2))
               ! constant loads: by class integrals, and as the polynomial loads a_α + 0·x
               flat = constant_data_t(mu1=data%mu1, mu2=data%mu2, f1=data%a(1), f2=data%a(2))
               call flat_loads%init(space, mesh, flat)
               call check(err, flat_loads%constant .and. .not. allocated(flat_loads%moments), 'constant loads stored')
               call discretization_flux(space, shapes, no_signatures, mesh, 0, colors, mu, flat_loads, iterate, scratch, &
                                        flat_sigma, ok)
               flat_poly = data
               flat_poly%b = 0.0_dp
               flat_poly%c = 0.0_dp
               call loads%init(space, mesh, flat_poly)
               call discretization_flux(space, shapes, no_signatures, mesh, 0, colors, mu, loads, iterate, scratch, &
                                        levels(1)%sigma, ok)
               call check(err, maxval(abs(flat_sigma - levels(1)%sigma)) <= 1.0e-13_dp*maxval(abs(flat_sigma)), &
                          'constant loads by class integrals')
               call loads%init(space, mesh, data)
               call check(err, .not. loads%constant, 'polynomial loads integrated')
               call discretization_flux(space, shapes, no_signatures, mesh, 0, colors, mu, loads, iterate, scratch, &
                                        levels(1)%sigma, ok)
               call check(err, ok, 'patch systems regular')
               dev = 0.0_dp
               do t = 1, mesh%nt
                  v = mesh%triangles(:, t)
                  ! q_k at the vertices: 1, (v − barycentre)/h_K
                  q(1, :) = 1.0_dp
                  q(2:3, :) = (mesh%vertices(:, v) - spread(sum(mesh%vertices(:, v), dim=2)/3, 2, 3))/mesh%diameter_of(t)
                  do alpha = 1, 2
                     fv = [(data%load(alpha, mesh%vertices(:, v(j))), j=1, 3)]
                     do i = 1, 3
                        do k = 1, space%n_div
                           exact = mesh%area(t)*dot_product(fv, matmul(tri(i, :, :), q(k, :)))
                           dev = max(dev, abs(loads%moments(k, i, t, alpha) - exact))
                        end do
                     end do
                  end do
               end do
               call check(err, dev <= 1.0e-14_dp*maxval(abs(loads%moments)), 'load moments exact')
               dev = 0.0_dp
               scale = 0.0_dp
               do t = 1, mesh%nt
                  v = mesh%triangles(:, t)
                  frame = make_frame(mesh%vertices(:, v))
                  do alpha = 1, 2
                     lhs = 0.0_dp
                     rhs = sum(loads%moments(:, :, t, alpha), dim=2)
                     do k = 1, space%rule%n
                        x = matmul(mesh%vertices(:, v), space%rule%bary(:, k))
                        w = space%rule%weights(k)*mesh%area(t)
                        lhs = lhs + w*dot_product(space%divergence_values(frame, x), levels(1)%sigma(:, t, alpha)) &
                              *space%div_test_values(frame, x)
                        rhs = rhs + w*(lambda_sign(alpha)*dot_product(lambda(v), space%rule%bary(:, k)) &
                                       - dot_product(r(:, t, alpha), space%rule%bary(:, k)))*space%div_test_values(frame, x)
                     end do
                     dev = max(dev, maxval(abs(lhs - rhs)))
                     scale = max(scale, maxval(abs(rhs)), mu(alpha)*norm2(grad_u(:, t, alpha))*mesh%area(t)/mesh%diameter_of(t))
                  end do
               end do
               call check(err, dev <= 1.0e-12_dp*scale, 'divergence moments of sigma_disc on the '//trim(domains(domain)))
               levels(1)%level = 0
               call check_normal_continuity(err, space, h, levels, 1.0e-12_dp, 'sigma_disc')
            end do
         end associate
      end do
   end subroutine test_disc_flux

   !> σ_alg on a twice refined square, with 1, 2 and 3 meshes: for RT1 the divergences of all
   !> levels add up to r_α at every quadrature point of every finest triangle, for RT0 to its
   !> mean; σ·n is continuous across the finest interior edges.
   subroutine test_alg_flux(err)
      type(error_t), allocatable, intent(out) :: err
      !> the generic path's per-thread scratch, the one-rank halo and ghost layer
      type(generic_scratch_t), allocatable :: scratch(:)
      type(halo_t) :: halo
      type(ghost_cells_t) :: ghosts
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(rt_space_t) :: space
      type(algebraic_flux_t) :: alg
      type(shape_classes_t) :: shapes
      !> no signatures: the general path of every patch is what this test checks
      type(patch_table_t) :: no_signatures
      type(evaluated_iterate_t) :: iterate
      real(dp), allocatable :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :)
      real(dp) :: x(2), value(2), div, r_x, dev
      integer(ip) :: t
      integer :: order, n_meshes, alpha, k
      character(len=40) :: what

      call mesh_problem('square', 0.5_dp, 2, data, h, p, err)
      if (allocated(err)) return
      call path_fixtures(h, p, scratch, halo, ghosts)
      call iterate_fields(p, h%meshes(2), random_vector(3*p%n, 30), lambda, grad_u, residual, r, iterate)
      associate (mesh => h%meshes(2))
         do order = 0, 1
            call space%init(order)
            do n_meshes = 1, 3
               write (what, '("RT",i0,", ",i0," meshes")') order, n_meshes
               call alg%init(space, h, data, n_meshes, .true., huge(1_ip), 1.0_dp, err)
               if (allocated(err)) return
               call shapes%init(space, h, err)
               if (allocated(err)) return
               call alg%take_residual(h, residual, p%interior)
               call alg%compute(shapes, h, iterate, no_signatures, no_signatures, scratch, p, halo, ghosts, err)
               if (allocated(err)) return
               call check(err, size(alg%levels) == max(1, n_meshes - 1), 'one flux part per level with patches')
               dev = 0.0_dp
               do t = 1, mesh%nt
                  do k = 1, merge(1, space%rule%n, order == 0)
                     ! RT0 divergences are constant: compare with the mean of r, at the barycentre
                     x = matmul(mesh%vertices(:, mesh%triangles(:, t)), merge(spread(1.0_dp/3, 1, 3), space%rule%bary(:, k), &
                                                                              order == 0))
                     do alpha = 1, 2
                        call flux_sum(space, h, alg%levels, t, x, alpha, value, div)
                        r_x = merge(sum(r(:, t, alpha))/3, dot_product(r(:, t, alpha), space%rule%bary(:, k)), order == 0)
                        dev = max(dev, abs(div - r_x))
                     end do
                  end do
               end do
               call check(err, dev <= 1.0e-11_dp*maxval(abs(r)), 'sum of level divergences = r, '//trim(what))
               call check_normal_continuity(err, space, h, alg%levels, 1.0e-11_dp, 'sigma_alg, '//trim(what))
            end do
         end do
      end associate
   end subroutine test_alg_flux

   ! ---- fixtures and helpers ----

   pure real(dp) function poly_load(self, alpha, x)
      class(poly_data_t), intent(in) :: self
      integer, intent(in) :: alpha
      real(dp), intent(in) :: x(2)

      poly_load = self%a(alpha) + dot_product(self%b(:, alpha), x) + self%c(alpha)*x(1)*x(2)
   end function poly_load

   !> What the patch paths take besides the fluxes' data: the generic path's scratch for each
   !> thread, and a one-rank run's halo and ghost layer.
   subroutine path_fixtures(h, p, scratch, halo, ghosts)
      type(mesh_hierarchy_t), intent(in) :: h
      type(discrete_problem_t), intent(in) :: p
      type(generic_scratch_t), allocatable, intent(out) :: scratch(:)
      type(halo_t), intent(out) :: halo
      type(ghost_cells_t), intent(out) :: ghosts

      type(comm_t) :: one_rank

      allocate (scratch(0:omp_get_max_threads() - 1))
      halo = p%halo
      call ghosts%init(one_rank, h%meshes(0))
   end subroutine path_fixtures

   !> The discrete problem of `data` (μ2 = 2μ1) on the unit disk (boundary spacing half the
   !> interior one) or the square (−1, 1)², of mesh size coarse_h, refined `levels` times.
   subroutine mesh_problem(domain, coarse_h, levels, data, h, p, err)
      character(len=*), intent(in) :: domain
      real(dp), intent(in) :: coarse_h
      integer, intent(in) :: levels
      type(poly_data_t), intent(inout) :: data
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: coarse

      if (domain == 'disk') then
         call make_disk(coarse_h, coarse_h/2, coarse, err)
      else
         call make_square(coarse_h, coarse, err)
      end if
      if (allocated(err)) return
      call h%init(coarse, levels, err)
      if (allocated(err)) return
      data%mu2 = 2*data%mu1
      call p%init(h%meshes(levels), data, err)
   end subroutine mesh_problem

   !> A known-solution case on a disk whose boundary is well resolved (boundary spacing a third
   !> of the interior one, twice refined: the polygon's geometric error, invisible to the
   !> estimators, stays well below the discretization error), solved by exact Newton-min.
   subroutine solved_disk(exact, data, h, p, res, err)
      !> exact_radial or exact_bbbv
      integer, intent(in) :: exact
      class(problem_data_t), allocatable, intent(out) :: data
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(newton_result_t), intent(out) :: res
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: coarse
      type(newton_options_t) :: options
      real(dp), allocatable :: x0(:)

      call make_problem(exact, 1.0_dp, 2.0_dp, -1.0_dp, 3.0_dp, 0.05_dp, data, err)
      if (allocated(err)) return
      call make_disk(0.45_dp, 0.15_dp, coarse, err)
      if (allocated(err)) return
      call h%init(coarse, 2, err)
      if (allocated(err)) return
      call p%init(h%meshes(2), data, err)
      if (allocated(err)) return
      options%verbose = .false.
      options%linear = method_direct
      x0 = [spread(p%g, 1, p%n), spread(0.0_dp, 1, 2*p%n)]
      call newton_solve(p, options, x0, res, err)
      if (.not. allocated(err)) call check(err, res%converged, 'Newton did not converge: '//res%status)
   end subroutine solved_disk

   !> Nodal λ_h, ∇u_α per triangle, nodal residuals and their lifting r_α for the iterate x, by
   !> whole-mesh loops, and the same iterate as the flux reconstructions take it.
   subroutine iterate_fields(p, mesh, x, lambda, grad_u, residual, r, iterate)
      type(discrete_problem_t), intent(in) :: p
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:)
      real(dp), allocatable, intent(out) :: lambda(:), grad_u(:, :, :), residual(:, :), r(:, :, :)
      type(evaluated_iterate_t), intent(out) :: iterate

      real(dp), allocatable :: u(:, :), work(:)
      integer(ip) :: n, t
      integer :: alpha

      n = p%n
      allocate (grad_u(2, mesh%nt, 2), residual(mesh%nv, 2), r(3, mesh%nt, 2))
      u = reshape([p%to_nodal(x(1:n), p%g), p%to_nodal(x(n + 1:2*n), 0.0_dp)], [mesh%nv, 2])
      lambda = p%to_nodal(x(2*n + 1:3*n), 0.0_dp)
      allocate (work(n))
      call algebraic_residuals(p, x, residual, work)
      do alpha = 1, 2
         do t = 1, mesh%nt
            grad_u(:, t, alpha) = matmul(p1_gradients(mesh, t), u(mesh%triangles(:, t), alpha))
         end do
      end do
      r = lifting_by_local_solves(mesh, residual)
      call iterate%init(mesh)
      iterate%u = u
      iterate%lambda = lambda
      iterate%shares = residual
      call iterate%set_shares(mesh)
   end subroutine iterate_fields

   !> The residual lifting by its definition, independently of the code's closed forms: on each
   !> triangle, the P1 mass matrix |t|/12 (1 + δ_ij) of its interior vertices solved (LU) for
   !> R_α(a)/N_a; zero at boundary vertices.
   function lifting_by_local_solves(mesh, residual) result(r)
      type(mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: residual(:, :)
      real(dp), allocatable :: r(:, :, :)

      real(dp) :: m(3, 3), b(3, 2)
      integer :: free(3), n_free, i, j, piv(3)
      integer(ip) :: t, a
      logical :: ok

      allocate (r(3, mesh%nt, 2))
      r = 0.0_dp
      do t = 1, mesh%nt
         n_free = 0
         do i = 1, 3
            a = mesh%triangles(i, t)
            if (mesh%boundary_vertex(a)) cycle
            n_free = n_free + 1
            free(n_free) = i
            b(n_free, :) = residual(a, :)/(mesh%patch_ptr(a + 1) - mesh%patch_ptr(a))
         end do
         if (n_free == 0) cycle
         do i = 1, n_free
            do j = 1, n_free
               m(i, j) = mesh%area(t)/12*merge(2.0_dp, 1.0_dp, i == j)
            end do
         end do
         call lu_factor(m(1:n_free, 1:n_free), piv(1:n_free), ok)
         call lu_solve(m(1:n_free, 1:n_free), piv(1:n_free), b(1:n_free, :))
         r(free(1:n_free), t, :) = b(1:n_free, :)
      end do
   end function lifting_by_local_solves

   !> Σ over the flux parts (ascending levels) of σ_l(x) and ∇·σ_l(x), x in finest triangle t,
   !> each part taken on the ancestor of t on its level.
   subroutine flux_sum(space, h, levels, t, x, alpha, value, div)
      type(rt_space_t), intent(in) :: space
      type(mesh_hierarchy_t), intent(in) :: h
      type(level_flux_t), intent(in) :: levels(:)
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: x(2)
      integer, intent(in) :: alpha
      real(dp), intent(out) :: value(2), div

      type(rt_frame_t) :: frame
      integer(ip) :: anc
      integer :: j, level

      value = 0.0_dp
      div = 0.0_dp
      anc = t
      level = h%levels
      do j = size(levels), 1, -1
         do while (level > levels(j)%level)
            anc = parent_triangle(anc)
            level = level - 1
         end do
         frame = make_frame(h%meshes(level)%vertices(:, h%meshes(level)%triangles(:, anc)))
         value = value + matmul(space%flux_values(frame, x), levels(j)%sigma(:, anc, alpha))
         div = div + dot_product(space%divergence_values(frame, x), levels(j)%sigma(:, anc, alpha))
      end do
   end subroutine flux_sum

   !> |σ·n| jumps across the finest interior edges, at 3 Gauss points each, below tol max|σ|.
   subroutine check_normal_continuity(err, space, h, levels, tol, what)
      type(error_t), allocatable, intent(inout) :: err
      type(rt_space_t), intent(in) :: space
      type(mesh_hierarchy_t), intent(in) :: h
      type(level_flux_t), intent(in) :: levels(:)
      real(dp), intent(in) :: tol
      character(len=*), intent(in) :: what

      real(dp) :: a(2), b(2), normal(2), x(2), s1(2), s2(2), d1, d2, jump, biggest
      integer(ip) :: e
      integer :: g, alpha
      character(len=160) :: msg

      jump = 0.0_dp
      biggest = 0.0_dp
      associate (mesh => h%meshes(h%levels))
         do e = 1, mesh%ne
            if (mesh%boundary_edge(e)) cycle
            a = mesh%vertices(:, mesh%edges(1, e))
            b = mesh%vertices(:, mesh%edges(2, e))
            normal = [b(2) - a(2), a(1) - b(1)]/norm2(b - a)
            do g = 1, 3
               x = a + 0.5_dp*(1 + edge_gauss(1, g))*(b - a)
               do alpha = 1, 2
                  call flux_sum(space, h, levels, mesh%edge_triangles(1, e), x, alpha, s1, d1)
                  call flux_sum(space, h, levels, mesh%edge_triangles(2, e), x, alpha, s2, d2)
                  jump = max(jump, abs(dot_product(s1 - s2, normal)))
                  biggest = max(biggest, norm2(s1), norm2(s2))
               end do
            end do
         end do
      end associate
      write (msg, '(a,": normal jump ",es9.2," vs max |sigma| ",es9.2)') what, jump, biggest
      call check(err, jump <= tol*biggest, trim(msg))
   end subroutine check_normal_continuity

   !> n uniform values in [−1/2, 1/2), reproducible from `seed`.
   function random_vector(n, seed) result(v)
      integer(ip), intent(in) :: n
      integer, intent(in) :: seed
      real(dp), allocatable :: v(:)

      integer, allocatable :: state(:)
      integer :: k, i

      call random_seed(size=k)
      state = [(seed*7919 + 104729*i, i=1, k)]
      call random_seed(put=state)
      allocate (v(n))
      call random_number(v)
      v = v - 0.5_dp
   end function random_vector
end module test_estimate
