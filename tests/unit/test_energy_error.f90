!> The energy error of a run's iterates (src/fortran/fem/twomem_fem_error.f90's exact_energy_t,
!> the exact solution's part integrated once) against the direct adaptive integration and, where
!> the two disagree, against an independent uniform subdivision of the element.
module test_energy_error
   use twomem_base_kinds, only: dp, ip
   use twomem_base_options, only: exact_radial, exact_bbbv
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_fem_assembly, only: p1_gradients
   use twomem_fem_error, only: energy_error_per_element, exact_energy_t
   use twomem_fem_quadrature, only: quadrature_t, triangle_rule
   use twomem_newton_solver, only: newton_result_t
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   use test_estimate, only: solved_disk, random_vector
   implicit none
   private

   public :: collect_energy_error

contains

   subroutine collect_energy_error(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('cached_energy_error', test_cached_energy_error)]
   end subroutine collect_energy_error

   !> The energy error from the exact solution's integrated part (exact_energy_t, as runs follow
   !> it through their iterates) against the direct adaptive integration, on both known solutions
   !> (second derivatives jump on the free boundary) and for fields near and far from them: the
   !> discrete solution, the same perturbed by 1e-3, and zero. Where the two adaptive rules
   !> disagree (elements on the free boundary, where a rule pair can agree by accident), both
   !> are compared with an independent uniform subdivision: the cached one must match it, and the
   !> total is compared with the direct one corrected there.
   subroutine test_cached_energy_error(err)
      type(error_t), allocatable, intent(out) :: err
      character(len=6), parameter :: cases(2) = ['radial', 'bbbv  ']
      integer, parameter :: kinds(2) = [exact_radial, exact_bbbv]
      type(mesh_hierarchy_t) :: h
      class(problem_data_t), allocatable :: data
      type(discrete_problem_t) :: p
      type(newton_result_t) :: res
      type(exact_energy_t) :: cache
      real(dp), allocatable :: u1(:), u2(:), noise(:), direct(:), cached(:)
      real(dp) :: reference
      integer :: c, field, n_disagree
      integer(ip) :: t
      character(len=32) :: what

      do c = 1, 2
         call solved_disk(kinds(c), data, h, p, res, err)
         if (allocated(err)) return
         associate (mesh => h%meshes(2))
            call cache%init(mesh, data)
            ! a fixed seed: the direct rule's errors depend on the field
            noise = random_vector(mesh%nv, 30 + c)
            do field = 1, 3
               u1 = p%to_nodal(res%x(1:p%n), p%g)
               u2 = p%to_nodal(res%x(p%n + 1:2*p%n), 0.0_dp)
               if (field == 2) then
                  u1 = u1 + 1.0e-3_dp*noise
                  u2 = u2 - 1.0e-3_dp*noise(mesh%nv:1:-1)
               else if (field == 3) then
                  u1 = 0.0_dp
                  u2 = 0.0_dp
               end if
               direct = energy_error_per_element(mesh, data, u1, u2)
               cached = cache%per_element(mesh, u1, u2)
               write (what, '(a,", field ",i0)') trim(cases(c)), field
               n_disagree = 0
               do t = 1, mesh%nt
                  if (abs(cached(t) - direct(t)) <= 1.0e-8_dp*direct(t)) cycle
                  n_disagree = n_disagree + 1
                  reference = uniform_energy(mesh, data, t, u1, u2, 64)
                  ! the total's reference takes the better integral where the two disagree
                  direct(t) = reference
                  call check(err, abs(cached(t) - reference) <= 1.0e-6_dp*reference, &
                             'cached energy error on a free-boundary element: '//what)
                  if (allocated(err)) return
               end do
               call check(err, n_disagree <= mesh%nt/20, 'adaptive rules disagree on few elements: '//what)
               call check(err, abs(norm2(cached) - norm2(direct)) < 1.0e-7_dp*norm2(direct), &
                          'cached energy error total: '//what)
               if (allocated(err)) return
            end do
         end associate
      end do
   end subroutine test_cached_energy_error

   !> (Σ_α μ_α ‖∇(u_α − u_αh)‖²_T)^{1/2} on triangle t by the degree-8 rule on each of the n²
   !> triangles of its uniform subdivision.
   function uniform_energy(mesh, data, t, u1, u2, n) result(e)
      type(mesh_t), intent(in) :: mesh
      class(problem_data_t), intent(in) :: data
      integer(ip), intent(in) :: t
      real(dp), intent(in) :: u1(:), u2(:)
      integer, intent(in) :: n
      real(dp) :: e

      type(quadrature_t) :: rule
      real(dp) :: grad(2, 3), gh(2, 2), p(2, 3), corner(2, 3), x(2), u(3), gx(2, 2), a(2), b(2)
      integer :: i, j, q, flip

      rule = triangle_rule(8)
      grad = p1_gradients(mesh, t)
      gh(:, 1) = matmul(grad, u1(mesh%triangles(:, t)))
      gh(:, 2) = matmul(grad, u2(mesh%triangles(:, t)))
      p = mesh%vertices(:, mesh%triangles(:, t))
      a = (p(:, 2) - p(:, 1))/n
      b = (p(:, 3) - p(:, 1))/n
      e = 0.0_dp
      do i = 0, n - 1
         do j = 0, n - 1 - i
            do flip = 0, merge(1, 0, i + j < n - 1)
               if (flip == 0) then
                  corner = reshape([p(:, 1) + i*a + j*b, p(:, 1) + (i + 1)*a + j*b, p(:, 1) + i*a + (j + 1)*b], [2, 3])
               else
                  corner = reshape([p(:, 1) + (i + 1)*a + (j + 1)*b, p(:, 1) + i*a + (j + 1)*b, &
                                    p(:, 1) + (i + 1)*a + j*b], [2, 3])
               end if
               do q = 1, rule%n
                  x = matmul(corner, rule%bary(:, q))
                  call data%exact(x, u, gx)
                  e = e + rule%weights(q)*(data%mu1*sum((gx(:, 1) - gh(:, 1))**2) + &
                                           data%mu2*sum((gx(:, 2) - gh(:, 2))**2))
               end do
            end do
         end do
      end do
      e = sqrt(e*mesh%area(t)/n**2)
   end function uniform_energy
end module test_energy_error
