!> The a posteriori estimators' values (twomem_estimate_estimators): at the discrete solution
!> (η_alg, η_lin and η_nonc,2 vanish, η bounds the energy error with a fair effectivity), at a
!> random nonconforming iterate (every term against its closed form), the Poincaré constants,
!> the local stopping criteria, and the run's last evaluation after `end_evaluations`. Expected
!> values are computed here, not taken from the code under test.
module test_estimator_values
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: exact_radial, exact_bbbv, domain_disk, domain_square, domain_gmsh
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_fem_error, only: energy_error_per_element
   use twomem_newton_solver, only: newton_result_t
   use twomem_estimate_estimators, only: estimator_t, estimates_t, poincare_constant
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_refinement, only: square_hierarchy
   use test_estimate, only: solved_disk, random_vector, mesh_problem, poly_data_t
   implicit none
   private

   public :: collect_estimator_values

   real(dp), parameter :: pi = acos(-1.0_dp)

contains

   subroutine collect_estimator_values(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('at_discrete_solution', test_at_solution), &
               new_unittest('nonconforming_iterate', test_nonconforming), &
               new_unittest('poincare_constant', test_poincare), &
               new_unittest('local_criteria', test_local_criteria), &
               new_unittest('fields_after_end_evaluations', test_end_evaluations)]
   end subroutine collect_estimator_values

   !> At the Newton solution (exact linear solves) for both known solutions, RT0 and RT1: the
   !> algebraic residual, hence σ_alg, is round-off (η_alg ≪ η_disc); s_h = u_h and λ_h ≥ 0, so
   !> η_lin vanishes (up to the round-off of the active rows u1 − u2 = 0); η_total bounds the
   !> energy error (Theorem 5.1) without being wildly pessimistic.
   subroutine test_at_solution(err)
      type(error_t), allocatable, intent(out) :: err
      character(len=6), parameter :: cases(2) = ['radial', 'bbbv  ']
      integer, parameter :: kinds(2) = [exact_radial, exact_bbbv]
      type(mesh_hierarchy_t) :: h
      class(problem_data_t), allocatable :: data
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res
      type(estimator_t) :: estimator
      type(estimates_t) :: est
      real(dp) :: energy
      integer :: c, order
      character(len=16) :: what

      do c = 1, 2
         call solved_disk(kinds(c), data, h, p, res, err)
         if (allocated(err)) return
         energy = norm2(energy_error_per_element(h%meshes(2), data, p%to_nodal(res%x(1:p%n), p%g), &
                                                 p%to_nodal(res%x(p%n + 1:2*p%n), 0.0_dp)))
         do order = 0, 1
            write (what, '(a," RT",i0)') trim(cases(c)), order
            call estimator%init(h, data, order, 3, poincare_constant(domain_disk, 2.0_dp), err)
            if (allocated(err)) return
            call estimator%evaluate(h, data, p, res%x, est, err)
            if (allocated(err)) return
            call check(err, est%alg < 1.0e-10_dp*est%disc, 'eta_alg negligible at the solution: '//what)
            call check(err, est%nonc2 == 0.0_dp, 'eta_nonc2 = 0 at the solution: '//what)
            call check(err, est%lin <= 1.0e-10_dp*est%disc, 'eta_lin = 0 at the solution: '//what)
            call check(err, est%total >= energy, 'eta_total >= energy error: '//what)
            call check(err, est%total <= 3*energy, 'effectivity below 3: '//what)
         end do
      end do
   end subroutine test_at_solution

   !> A random iterate (u1 < u2 and λ < 0 at many vertices) with a load x1 x2 outside P1: η_nonc,1
   !> = |||s_h − u_h|||, η_nonc,2 = C‖λ⁻‖, η_nonc,3 = 2C‖λ⁺‖η_nonc,1 (parts of λ integrated
   !> exactly on the clipped triangles), η_lin = η_nonc,1 + η_nonc,2 + √η_nonc,3, the RT1
   !> oscillation (h_K/π)μ^{−1/2}‖f − Π_1 f‖ (Π_1 in the barycentric basis), and the components
   !> bound the total (Cor. 5.6).
   subroutine test_nonconforming(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(estimator_t) :: estimator
      type(estimates_t) :: est, totals
      real(dp), allocatable :: x(:), u(:, :), ds(:, :), lambda(:)
      real(dp) :: c_omega, nonc1, neg, pos, osc, g(2, 3), f(7), b(3), mu(2)
      integer(ip) :: n, t, v(3)
      integer :: alpha, k

      data%c = [2.0_dp, -1.5_dp]
      call mesh_problem('disk', 0.5_dp, 1, data, h, p, err)
      if (allocated(err)) return
      n = p%n
      x = random_vector(3*n, 40)
      call estimator%init(h, data, 1, 2, poincare_constant(domain_disk, 2.0_dp), err)
      if (allocated(err)) return
      call estimator%evaluate(h, data, p, x, est, err)
      if (allocated(err)) return
      mu = [p%mu1, p%mu2]
      c_omega = poincare_constant(domain_disk, 2.0_dp)*sqrt(1/mu(1) + 1/mu(2))
      associate (mesh => h%meshes(1))
         u = reshape([p%to_nodal(x(1:n), p%g), p%to_nodal(x(n + 1:2*n), 0.0_dp)], [mesh%nv, 2])
         lambda = p%to_nodal(x(2*n + 1:), 0.0_dp)
         ! s_h − u_h: ±(u2 − u1)/2 where u1 < u2
         ds = spread(0.5_dp*max(0.0_dp, u(:, 2) - u(:, 1)), 2, 2)*spread([1.0_dp, -1.0_dp], 1, mesh%nv)
         nonc1 = 0.0_dp
         neg = 0.0_dp
         pos = 0.0_dp
         osc = 0.0_dp
         do t = 1, mesh%nt
            v = mesh%triangles(:, t)
            g = p1_gradients(mesh, t)
            nonc1 = nonc1 + mesh%area(t)*(mu(1)*sum(matmul(g, ds(v, 1))**2) + mu(2)*sum(matmul(g, ds(v, 2))**2))
            neg = neg + positive_square(mesh%area(t), -lambda(v))
            pos = pos + positive_square(mesh%area(t), lambda(v))
            do alpha = 1, 2
               ! Π_1 f = Σ c_i λ_i with c = M⁻¹ b, b_i = ∫ f λ_i, M⁻¹ = (12/|K|)(I − 11ᵀ/4); the
               ! degree-5 rule integrates (f − Π_1 f)² exactly
               do k = 1, 7
                  f(k) = data%load(alpha, matmul(mesh%vertices(:, v), estimator%space%rule%bary(:, k)))
               end do
               b = mesh%area(t)*matmul(estimator%space%rule%bary, estimator%space%rule%weights*f)
               b = 12/mesh%area(t)*(b - sum(b)/4)
               osc = osc + (mesh%diameter_of(t)/pi)**2/mu(alpha)*mesh%area(t)* &
                     sum(estimator%space%rule%weights*(f - matmul(b, estimator%space%rule%bary))**2)
            end do
         end do
      end associate
      nonc1 = sqrt(nonc1)
      call check(err, nonc1 > 0.0_dp .and. neg > 0.0_dp .and. pos > 0.0_dp, 'u1 < u2, lambda < 0 and > 0 somewhere')
      call check_close(err, est%nonc1, nonc1, 1.0e-12_dp, 0.0_dp, 'eta_nonc1')
      call check_close(err, est%nonc2, c_omega*sqrt(neg), 1.0e-12_dp, 0.0_dp, 'eta_nonc2')
      call check_close(err, est%nonc3, 2*c_omega*sqrt(pos)*nonc1, 1.0e-12_dp, 0.0_dp, 'eta_nonc3')
      call check_close(err, est%lin, nonc1 + c_omega*sqrt(neg) + sqrt(2*c_omega*sqrt(pos)*nonc1), 1.0e-12_dp, 0.0_dp, &
                       'eta_lin')
      call check_close(err, est%osc, sqrt(osc), 1.0e-10_dp, 0.0_dp, 'eta_osc')
      call check(err, est%total <= (est%disc + est%lin + est%alg)*(1 + 1.0e-12_dp), 'total <= disc + lin + alg')
      ! the totals alone (the global stopping tests), then the fields of that same evaluation
      call estimator%evaluate(h, data, p, x, totals, err, fields=.false.)
      if (allocated(err)) return
      call check(err, .not. totals%has_fields(), 'no per-triangle arrays without fields')
      call check(err, all([totals%total, totals%disc, totals%lin, totals%alg, totals%osc, totals%contact] == &
                          [est%total, est%disc, est%lin, est%alg, est%osc, est%contact]), 'the same totals without fields')
      call estimator%element_fields(h, data, totals)
      call check(err, totals%has_fields(), 'fields added')
      call check(err, all(totals%flux_k == est%flux_k) .and. all(totals%disc_k == est%disc_k) .and. &
                 all(totals%alg_k == est%alg_k) .and. all(totals%lin_k == est%lin_k) .and. &
                 all(totals%nonc3_k == est%nonc3_k) .and. totals%total == est%total, 'the same fields added later')
   end subroutine test_nonconforming

   !> The disk's constant is 1/j_{0,1}: J_0 vanishes at its reciprocal (intrinsic bessel_j0) and
   !> changes sign there; the square's is 1/√λ_1 with λ_1 = π²/2; otherwise diameter/π.
   subroutine test_poincare(err)
      type(error_t), allocatable, intent(out) :: err
      real(dp) :: c

      c = poincare_constant(domain_disk, 2.0_dp)
      call check(err, abs(bessel_j0(1/c)) < 1.0e-15_dp, 'J_0(1/C) = 0')
      call check(err, bessel_j0(0.999_dp/c) > 0 .and. bessel_j0(1.001_dp/c) < 0, 'first zero of J_0')
      call check_close(err, poincare_constant(domain_square, 2*sqrt(2.0_dp)), 1/sqrt(pi**2/2), 1.0e-15_dp, 0.0_dp, 'square')
      call check_close(err, poincare_constant(domain_gmsh, 3.0_dp), 3/pi, 1.0e-15_dp, 0.0_dp, 'diameter/pi')
   end subroutine test_poincare

   !> (64a) compares the patch sum √Σ η_alg,K² with the min over the patch of γ max(η_disc, η_lin),
   !> (64b) η_lin,K with γ min_α η_disc,K,α. Hand-made values on the four triangles around the
   !> centre of the square, each case flipping one branch.
   subroutine test_local_criteria(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(estimates_t) :: est
      logical :: alg_ok, lin_ok

      call square_hierarchy(0, h, err)
      if (allocated(err)) return
      allocate (est%disc_k(2, 4), est%alg_k(2, 4), est%lin_k(4))
      est%disc_k = 1.0_dp
      est%lin_k = 0.1_dp
      est%alg_k = 0.2_dp
      call criteria('both hold', .true., .true.)
      ! each triangle's 0.3 is below 0.5, but the centre patch sums to √(4·0.09) = 0.6
      est%alg_k = 0.3_dp
      call criteria('patch sum, not max', .false., .true.)
      ! membrane 2 of triangle 1 tightens every patch containing it to 0.5·0.1; min over α in (64b)
      est%alg_k = 0.2_dp
      est%disc_k(2, 1) = 0.1_dp
      call criteria('small disc on one triangle', .false., .false.)
      ! a large η_lin lifts the bound again (max(disc, lin)) but fails (64b)
      est%lin_k(1) = 1.0_dp
      call criteria('max with eta_lin', .true., .false.)
      est%disc_k = 1.0_dp
      est%lin_k = 0.1_dp
      est%lin_k(3) = 0.25_dp
      call criteria('eta_lin above gamma disc', .true., .false.)

   contains

      subroutine criteria(what, alg_expected, lin_expected)
         character(len=*), intent(in) :: what
         logical, intent(in) :: alg_expected, lin_expected

         call est%local_criteria(h%meshes(0), 0.5_dp, 0.2_dp, alg_ok, lin_ok)
         call check(err, alg_ok .eqv. alg_expected, 'alg criterion: '//what)
         call check(err, lin_ok .eqv. lin_expected, 'lin criterion: '//what)
      end subroutine criteria
   end subroutine test_local_criteria

   !> The run's last evaluation: once `end_evaluations` has dropped what only evaluations need
   !> (patch factors, the shape classes' patch operators, the algebraic flux's coarse
   !> factorization and P2 fields), the element pass still gives the per-triangle fields of an
   !> evaluation that kept them, bit for bit; a later evaluation is refused. Non-constant loads
   !> (per-triangle load moments and oscillations) and two levels of algebraic flux.
   subroutine test_end_evaluations(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(poly_data_t) :: data
      type(discrete_problem_t) :: p
      type(estimator_t) :: kept, ended
      type(estimates_t) :: expected, est
      type(error_t), allocatable :: refused
      real(dp), allocatable :: x(:)

      data%c = [2.0_dp, -1.5_dp]
      call mesh_problem('disk', 0.5_dp, 2, data, h, p, err)
      if (allocated(err)) return
      x = random_vector(3*p%n, 41)
      call kept%init(h, data, 1, 3, poincare_constant(domain_disk, 2.0_dp), err)
      if (allocated(err)) return
      call kept%evaluate(h, data, p, x, expected, err, fields=.true.)
      if (allocated(err)) return
      call ended%init(h, data, 1, 3, poincare_constant(domain_disk, 2.0_dp), err)
      if (allocated(err)) return
      call ended%evaluate(h, data, p, x, est, err, fields=.false.)
      if (allocated(err)) return
      call check(err, .not. est%has_fields(), 'the evaluation for the stopping tests has no fields')
      if (allocated(err)) return
      call ended%end_evaluations()
      call ended%element_fields(h, data, est)
      call check(err, est%has_fields(), 'the element pass after end_evaluations made the fields')
      if (allocated(err)) return
      call check(err, all(est%disc_k == expected%disc_k) .and. all(est%alg_k == expected%alg_k) .and. &
                 all(est%flux_k == expected%flux_k) .and. all(est%osc_k == expected%osc_k) .and. &
                 all(est%contact_k == expected%contact_k) .and. all(est%nonc1_k == expected%nonc1_k) .and. &
                 all(est%nonc2_k == expected%nonc2_k), 'the per-triangle fields keep their bits')
      call check(err, est%total == expected%total .and. est%alg == expected%alg .and. est%disc == expected%disc, &
                 'the totals keep their bits')
      call check(err, any(expected%alg_k > 0) .and. any(expected%osc_k > 0), &
                 'the algebraic and oscillation fields are not zero (the comparison can fail)')
      if (allocated(err)) return
      call ended%evaluate(h, data, p, x, est, refused)
      call check(err, allocated(refused), 'an evaluation after end_evaluations is refused')
   end subroutine test_end_evaluations

   !> ∫_K (l⁺)² for l linear with vertex values l: with one positive vertex p the positive part
   !> lives on the triangle cut off at the zeros on its two edges, of area |K| s_j s_k, where it
   !> is l_p times a hat function; with two, the complement of the negative part of the whole.
   pure real(dp) function positive_square(area, l) result(s)
      real(dp), intent(in) :: area, l(3)

      if (count(l > 0) >= 2) then
         s = area/12*(sum(l**2) + sum(l)**2) - one_positive(-l)
      else
         s = one_positive(l)
      end if

   contains

      pure real(dp) function one_positive(m)
         real(dp), intent(in) :: m(3)

         integer :: p

         one_positive = 0.0_dp
         if (all(m <= 0)) return
         p = maxloc(m, dim=1)
         one_positive = area*m(p)**2/6*(m(p)/(m(p) - m(modulo(p, 3) + 1)))*(m(p)/(m(p) - m(modulo(p + 1, 3) + 1)))
      end function one_positive
   end function positive_square
end module test_estimator_values
