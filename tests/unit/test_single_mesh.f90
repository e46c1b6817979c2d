!> The estimators without red-refined descendants: the generic patch path (triangle operators
!> from each triangle's own geometry, nothing stored per class or per patch) against the class
!> path where both apply, and the one-level algebraic flux (its Riesz representer by conjugate
!> gradients, the remainder bounded by η_rem) against its definition and against the exact
!> single-mesh flux. Expected values are computed here: the residuals from the discrete
!> problem's matrices, the liftings by local mass solves (test_estimate), divergences at
!> quadrature points from the Raviart–Thomas basis.
module test_single_mesh
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: domain_disk, domain_square
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_generators, only: make_disk
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t, refinement_map_t
   use twomem_mesh_bisection, only: longest_edge_first, bisect_marked
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_linalg_csr, only: csr_t
   use twomem_linalg_multigrid, only: multigrid_transfer_t, multigrid_options_t
   use twomem_linalg_mg_preconditioner, only: mg_preconditioner_t
   use twomem_fem_transfer, only: interior_prolongations
   use twomem_estimate_raviart_thomas, only: rt_space_t, rt_frame_t, make_frame
   use twomem_estimate_estimators, only: estimator_t, estimates_t, poincare_constant
   use twomem_estimate_storage, only: tier_all, tier_single, tier_none
   use twomem_estimate_riesz, only: remainder_fraction, max_iterations
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   use test_estimate, only: random_vector, mesh_problem, poly_data_t, lifting_by_local_solves
   implicit none
   private

   public :: collect_single_mesh

   interface close
      module procedure close1, close3
   end interface close

   character(len=*), parameter :: fields(10) = [character(len=9) :: 'eta_total', 'eta_disc', 'eta_lin', 'eta_alg', &
                                                'eta_F', 'eta_osc', 'eta_C', 'eta_nonc1', 'eta_nonc2', 'eta_nonc3']

contains

   subroutine collect_single_mesh(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('generic_path_equals_class_path', test_generic_equals_classes), &
               new_unittest('bisected_mesh_classes_by_shape', test_bisected_classes), &
               new_unittest('one_level_flux_with_exact_riesz', test_one_level_exact), &
               new_unittest('one_level_flux_divergence_and_remainder', test_one_level_remainder), &
               new_unittest('one_level_flux_in_the_discretization_pass', test_one_pass)]
   end subroutine collect_single_mesh

   !> On a twice red-refined disk and square, for a random iterate (algebraic residual far from
   !> zero), RT0 and RT1: the estimators with the shape classes and patch signatures (factored
   !> patches; every table, or those of the finest mesh only, trimmed after factorization) and
   !> without (every patch on the generic path, every mass matrix per triangle) give the same
   !> discretization and algebraic flux coefficients on every triangle and the same per-element
   !> estimators and totals, to round-off. The algebraic flux uses the finest mesh alone
   !> (alg_meshes = 1), the construction every path has.
   subroutine test_generic_equals_classes(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=6), parameter :: domains(2) = ['disk  ', 'square']
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(estimator_t) :: classes, generic
      type(estimates_t) :: with_classes, without
      real(dp), allocatable :: x(:), a(:), b(:)
      real(dp) :: ta, tb
      integer :: domain, order, k, tier
      character(len=6), parameter :: tiers(2) = ['all   ', 'single']
      character(len=40) :: what

      do domain = 1, 2
         ! loads with an x1 x2 term: moments from the load's own quadrature (the discrete problem's
         ! too, so that the patch problems are compatible)
         data%c = [0.3_dp, -0.2_dp]
         call mesh_problem(trim(domains(domain)), merge(0.4_dp, 0.7_dp, domain == 1), 2, data, h, p, err)
         if (allocated(err)) return
         x = random_vector(3*p%n, 40 + domain)
         do order = 0, 1
            do tier = 1, 2
               write (what, '("RT",i0,", ",a,", ",a)') order, trim(domains(domain)), trim(tiers(tier))
               call classes%init(h, data, order, 1, 1.0_dp, err, tier=merge(tier_all, tier_single, tier == 1))
               if (allocated(err)) return
               call generic%init(h, data, order, 1, 1.0_dp, err, tier=tier_none)
               if (allocated(err)) return
               call check(err, classes%classes .and. .not. generic%classes, 'the two paths chosen, '//trim(what))
               call classes%evaluate(h, data, p, x, with_classes, err, fields=.true.)
               if (allocated(err)) return
               call generic%evaluate(h, data, p, x, without, err, fields=.true.)
               if (allocated(err)) return
               call check(err, close(generic%sigma, classes%sigma, 1.0e-11_dp), 'sigma_disc coefficients, '//trim(what))
               call check(err, close(generic%alg%levels(1)%sigma, classes%alg%levels(1)%sigma, 1.0e-11_dp), &
                          'sigma_alg coefficients, '//trim(what))
               do k = 1, size(fields)
                  call with_classes%field(trim(fields(k)), a, ta)
                  call without%field(trim(fields(k)), b, tb)
                  call check(err, close(b, a, 1.0e-11_dp) .and. abs(tb - ta) <= 1.0e-11_dp*abs(ta), &
                             trim(fields(k))//' per element and total, '//trim(what))
               end do
               if (allocated(err)) return
            end do
         end do
      end do
   end subroutine test_generic_equals_classes

   !> On a disk mesh bisected towards one corner of its quadrant (newest-vertex bisection, six
   !> rounds: triangles of every size, patches that mix them) taken as a single mesh, the classes
   !> found by shape (shape_classes_t%classify) are far fewer than the triangles, most patches
   !> get a signature, and the factored patches with the classes' operators at each triangle's
   !> own ratio give the generic path's discretization and algebraic fluxes and estimators to
   !> round-off, RT0 and RT1, for a random iterate.
   subroutine test_bisected_classes(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: coarse, fine
      type(refinement_map_t) :: map
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(estimator_t) :: classes, generic
      type(estimates_t) :: with_classes, without
      real(dp), allocatable :: x(:), a(:), b(:), centre(:, :)
      real(dp) :: ta, tb
      integer :: round, order, k, n_shapes
      integer(ip) :: t
      character(len=40) :: what

      call make_disk(0.4_dp, 0.2_dp, coarse, err)
      if (allocated(err)) return
      call longest_edge_first(coarse, err)
      if (allocated(err)) return
      do round = 1, 6
         allocate (centre(2, coarse%nt))
         do t = 1, coarse%nt
            centre(:, t) = sum(coarse%vertices(:, coarse%triangles(:, t)), dim=2)/3
         end do
         call bisect_marked(coarse, norm2(centre - spread([0.5_dp, 0.3_dp], 2, coarse%nt), dim=1) < 0.4_dp, fine, &
                            map, err)
         if (allocated(err)) return
         deallocate (centre)
         coarse = fine
      end do
      call h%init(coarse, 0, err)
      if (allocated(err)) return
      data%c = [0.3_dp, -0.2_dp]
      data%mu2 = 2*data%mu1
      call p%init(h%meshes(0), data, err)
      if (allocated(err)) return
      x = random_vector(3*p%n, 61)
      do order = 0, 1
         write (what, '("RT",i0,", bisected disk")') order
         call classes%init(h, data, order, 1, 1.0_dp, err, tier=tier_single)
         if (allocated(err)) return
         call generic%init(h, data, order, 1, 1.0_dp, err, tier=tier_none)
         if (allocated(err)) return
         n_shapes = classes%shapes%n_shapes()
         call check(err, classes%classes .and. .not. generic%classes .and. n_shapes > 0 .and. &
                    4*n_shapes < h%meshes(0)%nt, 'few shapes for many triangles, '//trim(what))
         call check(err, 2*count(classes%single%levels(0)%id > 0) > h%meshes(0)%nv, &
                    'most patches with a signature, '//trim(what))
         if (allocated(err)) return
         call classes%evaluate(h, data, p, x, with_classes, err, fields=.true.)
         if (allocated(err)) return
         call generic%evaluate(h, data, p, x, without, err, fields=.true.)
         if (allocated(err)) return
         call check(err, close(generic%sigma, classes%sigma, 1.0e-11_dp), 'sigma_disc coefficients, '//trim(what))
         call check(err, close(generic%alg%levels(1)%sigma, classes%alg%levels(1)%sigma, 1.0e-11_dp), &
                    'sigma_alg coefficients, '//trim(what))
         do k = 1, size(fields)
            call with_classes%field(trim(fields(k)), a, ta)
            call without%field(trim(fields(k)), b, tb)
            call check(err, close(b, a, 1.0e-11_dp) .and. abs(tb - ta) <= 1.0e-11_dp*abs(ta), &
                       trim(fields(k))//' per element and total, '//trim(what))
         end do
         if (allocated(err)) return
      end do
   end subroutine test_bisected_classes

   !> The one-level algebraic flux with an exact preconditioner (a one-level transfer: the
   !> V-cycle is a direct solve) takes one conjugate-gradient step, leaves a remainder at
   !> round-off and gives the flux of the exact single-mesh construction (the coarse problem
   !> on the finest mesh, solved directly), on a refined square and a single disk mesh, RT0
   !> and RT1.
   subroutine test_one_level_exact(err)
      type(error_t), allocatable, intent(out) :: err

      character(len=6), parameter :: domains(2) = ['square', 'disk  ']
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t), target :: p
      type(estimator_t) :: exact, one_level
      type(estimates_t) :: est_exact, est
      type(multigrid_transfer_t), target :: transfer
      type(mg_preconditioner_t) :: direct
      type(multigrid_options_t) :: options
      type(csr_t) :: none(0)
      real(dp), allocatable :: x(:)
      integer :: domain, order
      character(len=40) :: what

      do domain = 1, 2
         call mesh_problem(trim(domains(domain)), merge(0.5_dp, 0.1_dp, domain == 1), merge(2, 0, domain == 1), data, h, &
                           p, err)
         if (allocated(err)) return
         x = random_vector(3*p%n, 50 + domain)
         call transfer%init(none, err, n_coarsest=p%n)
         if (allocated(err)) return
         call direct%init(p%stiffness, transfer, 0, options, err)
         if (allocated(err)) return
         do order = 0, 1
            write (what, '("RT",i0,", ",a)') order, trim(domains(domain))
            call exact%init(h, data, order, 1, 1.0_dp, err, exact_max=huge(1_ip))
            if (allocated(err)) return
            call one_level%init(h, data, order, 1, 1.0_dp, err, exact_max=0_ip)
            if (allocated(err)) return
            call check(err, one_level%alg%one_level .and. .not. exact%alg%one_level, 'the two constructions, '//trim(what))
            call exact%evaluate(h, data, p, x, est_exact, err)
            if (allocated(err)) return
            call one_level%evaluate(h, data, p, x, est, err, precond=direct)
            if (allocated(err)) return
            call check(err, all(one_level%alg%riesz%iterations == 1), 'one step, '//trim(what))
            call check(err, est%alg_remainder <= 1.0e-9_dp*est%alg .and. est_exact%alg_remainder == 0.0_dp, &
                       'remainder at round-off, '//trim(what))
            call check(err, close(one_level%alg%levels(1)%sigma, exact%alg%levels(1)%sigma, 1.0e-9_dp), &
                       'sigma_alg = the exact single-mesh flux, '//trim(what))
            call check(err, abs(est%total - est_exact%total) <= 1.0e-9_dp*est_exact%total, 'eta, '//trim(what))
            if (allocated(err)) return
         end do
         call direct%release()
      end do
   end subroutine test_one_level_exact

   !> The one-level algebraic flux with conjugate gradients that stop on their test with a
   !> sizeable remainder, on a single disk mesh without a preconditioner (generic patches) and on
   !> a twice refined square with V-cycles on its three levels (the finest mesh's signatures and
   !> the classes without the multilevel tables, tier_single): on every triangle the divergence
   !> of σ_alg equals r − r',
   !> the lifting of K ρ̃ (RT1 at each quadrature point, RT0 its mean), with ρ̃ and K ρ̃ recomputed
   !> here; η_rem is h_Ω C_PF (Σ_α ‖r'_α‖²/μ_α)^½ with r' the lifting of R − K ρ̃ (RT0: its mean),
   !> each recomputed by local mass solves; the conjugate gradients stopped on their test or at
   !> their cap; and the bound's parts add up (η_alg and η_1 carry η_rem).
   subroutine test_one_level_remainder(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t), target :: p
      type(estimator_t) :: estimator
      type(estimates_t) :: est
      type(rt_space_t) :: space
      type(rt_frame_t) :: frame
      real(dp), allocatable :: x(:), residual(:, :), krho(:, :), rest(:, :), rho(:), k_rho(:), lift(:, :, :), lift_rest(:, :, :)
      real(dp) :: poincare, dev, scale, value, div, norm_sq(2), energy(2), mu(2), xq(2)
      integer(ip) :: t, n, v(3)
      integer :: order, alpha, q, c, finest
      character(len=30) :: what
      type(multigrid_transfer_t), target :: transfer
      type(mg_preconditioner_t) :: vcycle

      do c = 1, 2
         finest = merge(0, 2, c == 1)
         call one_level_case(c, data, h, p, transfer, vcycle, err)
         if (allocated(err)) return
         n = p%n
         mu = [p%mu1, p%mu2]
         poincare = poincare_constant(merge(domain_disk, domain_square, c == 1), 2.0_dp)
         ! random values: a residual of every frequency
         x = random_vector(3*n, 60)
         if (allocated(residual)) deallocate (residual, krho, rest, k_rho)
         allocate (residual(h%meshes(finest)%nv, 2), krho(h%meshes(finest)%nv, 2), rest(h%meshes(finest)%nv, 2), k_rho(n))
         associate (mesh => h%meshes(finest))
            do alpha = 1, 2
               call p%stiffness%matvec(x((alpha - 1)*n + 1:alpha*n), k_rho)
               residual(:, alpha) = 0.0_dp
               residual(p%interior, alpha) = p%f((alpha - 1)*n + 1:alpha*n) - mu(alpha)*k_rho &
                                             + merge(1.0_dp, -1.0_dp, alpha == 1)*p%mass*x(2*n + 1:)
            end do
            do order = 0, 1
               write (what, '("RT",i0,", ",a)') order, merge('single mesh ', 'V-cycles    ', c == 1)
               call space%init(order)
               if (c == 1) then
                  call estimator%init(h, data, order, 1, poincare, err, exact_max=0_ip)
                  if (allocated(err)) return
                  call estimator%evaluate(h, data, p, x, est, err)
               else
                  call estimator%init(h, data, order, 3, poincare, err, tier=tier_single, exact_max=0_ip)
                  if (allocated(err)) return
                  call check(err, estimator%classes .and. estimator%alg%base == 2, 'tier_single: classes, one level')
                  call estimator%evaluate(h, data, p, x, est, err, precond=vcycle)
               end if
               if (allocated(err)) return
               call check(err, estimator%alg%one_level, 'one-level construction, '//what)
               call check(err, all(estimator%alg%riesz%iterations > 1), 'conjugate gradients iterated, '//what)
               ! ρ̃, K ρ̃ and the remainder R − K ρ̃ at the vertices
               do alpha = 1, 2
                  rho = estimator%alg%riesz%rho%u(p%interior, alpha)
                  call p%stiffness%matvec(rho, k_rho)
                  krho(:, alpha) = 0.0_dp
                  krho(p%interior, alpha) = k_rho
                  rest(:, alpha) = residual(:, alpha) - krho(:, alpha)
                  energy(alpha) = dot_product(rho, k_rho)
               end do
               lift = lifting_by_local_solves(mesh, krho)
               lift_rest = lifting_by_local_solves(mesh, rest)
               dev = 0.0_dp
               scale = maxval(abs(lift))
               norm_sq = 0.0_dp
               do t = 1, mesh%nt
                  v = mesh%triangles(:, t)
                  frame = make_frame(mesh%vertices(:, v))
                  do alpha = 1, 2
                     associate (c => estimator%alg%levels(1)%sigma(:, t, alpha), r => lift(:, t, alpha))
                        if (order == 0) then
                           ! the divergence is constant: against the mean of r − r'
                           div = dot_product(space%divergence_values(frame, frame%centre), c)
                           dev = max(dev, abs(div - sum(r)/3))
                        else
                           do q = 1, space%rule%n
                              xq = matmul(mesh%vertices(:, v), space%rule%bary(:, q))
                              div = dot_product(space%divergence_values(frame, xq), c)
                              value = dot_product(r, space%rule%bary(:, q))
                              dev = max(dev, abs(div - value))
                           end do
                        end if
                     end associate
                     associate (r => lift_rest(:, t, alpha))
                        if (order == 0) then
                           norm_sq(alpha) = norm_sq(alpha) + mesh%area(t)*(sum(r)/3)**2
                        else
                           norm_sq(alpha) = norm_sq(alpha) + mesh%area(t)/12*(sum(r**2) + sum(r)**2)
                        end if
                     end associate
                  end do
               end do
               call check(err, dev <= 1.0e-10_dp*scale, 'divergence of sigma_alg = r - r'', '//what)
               call check(err, abs(est%alg_remainder - poincare*sqrt(sum(norm_sq/mu))) <= 1.0e-10_dp*est%alg_remainder, &
                          'eta_rem from the lifted remainder, '//what)
               do alpha = 1, 2
                  call check(err, poincare*sqrt(norm_sq(alpha)) <= remainder_fraction*sqrt(energy(alpha))*(1 + 1.0e-8_dp) &
                             .or. estimator%alg%riesz%iterations(alpha) == max_iterations, 'stopping test met, '//what)
               end do
               call check(err, est%alg_remainder > 0.0_dp .and. est%alg >= est%alg_remainder, 'eta_alg carries eta_rem, '//what)
               call check(err, est%total <= (est%disc + est%lin + est%alg)*(1 + 1.0e-12_dp), 'eta <= the sum of its parts, '//what)
               if (allocated(err)) return
            end do
         end associate
      end do
   end subroutine test_one_level_remainder

   !> The one-level algebraic flux computed in the discretization flux's pass (a whole
   !> evaluation) against its own pass after an evaluation without it (`complete`), for the
   !> same random iterate: the same discretization and algebraic flux on every triangle and the
   !> same estimators, to round-off. On a single disk mesh without shape classes (tier_none:
   !> every patch generic; plain conjugate gradients) and a twice refined square whose finest
   !> patches have signatures (tier_single, V-cycles), RT0 and RT1.
   subroutine test_one_pass(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t), target :: p
      type(estimator_t) :: one_pass, two_passes
      type(estimates_t) :: est1, est2
      type(multigrid_transfer_t), target :: transfer
      type(mg_preconditioner_t) :: vcycle
      real(dp), allocatable :: x(:)
      integer :: order, c
      character(len=30) :: what

      do c = 1, 2
         call one_level_case(c, data, h, p, transfer, vcycle, err)
         if (allocated(err)) return
         x = random_vector(3*p%n, 70)
         do order = 0, 1
            write (what, '("RT",i0,", ",a)') order, merge('single mesh ', 'V-cycles    ', c == 1)
            if (c == 1) then
               call one_pass%init(h, data, order, 1, 1.0_dp, err, tier=tier_none, exact_max=0_ip)
               if (allocated(err)) return
               call two_passes%init(h, data, order, 1, 1.0_dp, err, tier=tier_none, exact_max=0_ip)
               if (allocated(err)) return
               call check(err, .not. one_pass%classes, 'no shape classes, '//what)
               call one_pass%evaluate(h, data, p, x, est1, err)
               if (allocated(err)) return
               call two_passes%evaluate(h, data, p, x, est2, err, algebraic=.false.)
               if (allocated(err)) return
               call two_passes%complete(h, data, est2, err, .false., p)
            else
               call one_pass%init(h, data, order, 3, 1.0_dp, err, tier=tier_single, exact_max=0_ip)
               if (allocated(err)) return
               call two_passes%init(h, data, order, 3, 1.0_dp, err, tier=tier_single, exact_max=0_ip)
               if (allocated(err)) return
               call check(err, one_pass%classes, 'patch signatures, '//what)
               call one_pass%evaluate(h, data, p, x, est1, err, precond=vcycle)
               if (allocated(err)) return
               call two_passes%evaluate(h, data, p, x, est2, err, algebraic=.false.)
               if (allocated(err)) return
               call two_passes%complete(h, data, est2, err, .false., p, vcycle)
            end if
            if (allocated(err)) return
            call check(err, one_pass%alg%one_level, 'one-level construction, '//what)
            call check(err, all(one_pass%alg%riesz%iterations > 1), 'conjugate gradients iterated, '//what)
            call check(err, close(one_pass%sigma, two_passes%sigma, 1.0e-12_dp), 'sigma_disc, '//what)
            call check(err, close(one_pass%alg%levels(1)%sigma, two_passes%alg%levels(1)%sigma, 1.0e-12_dp), &
                       'sigma_alg, '//what)
            call check(err, close([est1%disc, est1%alg, est1%alg_remainder, est1%lin, est1%total], &
                                  [est2%disc, est2%alg, est2%alg_remainder, est2%lin, est2%total], 1.0e-12_dp), &
                       'the estimators, '//what)
            if (allocated(err)) return
         end do
      end do
   end subroutine test_one_pass

   !> Case c of the one-level tests: 1 a single disk mesh (no preconditioner), 2 a twice refined
   !> square with `vcycle`, V-cycles on its three levels through `transfer`.
   subroutine one_level_case(c, data, h, p, transfer, vcycle, err)
      integer, intent(in) :: c
      type(poly_data_t), intent(inout) :: data
      type(mesh_hierarchy_t), intent(inout) :: h
      type(discrete_problem_t), target, intent(inout) :: p
      type(multigrid_transfer_t), target, intent(inout) :: transfer
      type(mg_preconditioner_t), intent(inout) :: vcycle
      type(error_t), allocatable, intent(out) :: err

      type(multigrid_options_t) :: options

      if (c == 1) then
         call mesh_problem('disk', 0.08_dp, 0, data, h, p, err)
         return
      end if
      call mesh_problem('square', 0.25_dp, 2, data, h, p, err)
      if (allocated(err)) return
      call transfer%init(interior_prolongations(h, 2), err)
      if (allocated(err)) return
      call vcycle%init(p%stiffness, transfer, 2, options, err)
   end subroutine one_level_case

   !> |a − b| ≤ rtol max|b| entrywise.
   logical function close1(a, b, rtol) result(ok)
      real(dp), intent(in) :: a(:), b(:), rtol

      ok = size(a) == size(b)
      if (ok) ok = maxval(abs(a - b)) <= rtol*maxval(abs(b))
   end function close1

   logical function close3(a, b, rtol) result(ok)
      real(dp), intent(in) :: a(:, :, :), b(:, :, :), rtol

      ok = all(shape(a) == shape(b))
      if (ok) ok = maxval(abs(a - b)) <= rtol*maxval(abs(b))
   end function close3
end module test_single_mesh
