!> P1 assembly: exactness on linear functions, zero row sums, lumped mass, loads, and the
!> Dirichlet lifting of the discrete problem.
module test_assembly
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_linalg_csr, only: csr_t
   use twomem_fem_problem, only: constant_data_t
   use twomem_fem_assembly, only: assemble_stiffness, lumped_mass, assemble_loads
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   use test_refinement, only: square_hierarchy
   implicit none
   private

   public :: collect_assembly

contains

   subroutine collect_assembly(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('stiffness_row_sums_zero', test_row_sums), &
               new_unittest('stiffness_energy_of_linears', test_linear_energy), &
               new_unittest('stiffness_symmetric', test_symmetric), &
               new_unittest('lumped_mass_and_load', test_mass_load), &
               new_unittest('lifting_reproduces_constant', test_lifting)]
   end subroutine collect_assembly

   subroutine test_row_sums(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(csr_t) :: k
      real(dp), allocatable :: y(:)

      call square_hierarchy(3, h, err)
      if (allocated(err)) return
      call assemble_stiffness(h%meshes(3), k)
      allocate (y(k%n))
      call k%matvec(spread(1.0_dp, 1, k%n), y)
      call check(err, maxval(abs(y)) < 100*epsilon(1.0_dp), 'constants in the kernel')
   end subroutine test_row_sums

   !> u = a·x + c, v = b·x + d: u^T K v = |Ω| a·b, and K u vanishes at interior vertices.
   subroutine test_linear_energy(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(csr_t) :: k
      real(dp), allocatable :: u(:), v(:), ku(:)

      call square_hierarchy(3, h, err)
      if (allocated(err)) return
      associate (m => h%meshes(3))
         call assemble_stiffness(m, k)
         u = 0.5_dp + 2*m%vertices(1, :) - 3*m%vertices(2, :)
         v = -1 + 0.25_dp*m%vertices(1, :) + m%vertices(2, :)
         allocate (ku(m%nv))
         call k%matvec(u, ku)
         call check_close(err, dot_product(ku, v), 4*(2*0.25_dp - 3), 1.0e-13_dp, 0.0_dp, 'u^T K v')
         call check(err, maxval(abs(pack(ku, .not. m%boundary_vertex))) < 1.0e-12_dp, &
                    'K u = 0 at interior vertices for linear u')
      end associate
   end subroutine test_linear_energy

   subroutine test_symmetric(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(csr_t) :: k
      integer(ip) :: i, m

      call square_hierarchy(2, h, err)
      if (allocated(err)) return
      call assemble_stiffness(h%meshes(2), k)
      do i = 1, k%n
         do m = k%row_ptr(i), k%row_ptr(i + 1) - 1
            call check_close(err, k%val(m), k%val(k%find(k%col(m), i)), 0.0_dp, 1.0e-15_dp, 'K symmetric')
         end do
      end do
   end subroutine test_symmetric

   subroutine test_mass_load(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(constant_data_t) :: data
      real(dp), allocatable :: loads(:, :)

      call square_hierarchy(2, h, err)
      if (allocated(err)) return
      data%f1 = 3.0_dp
      data%f2 = -2.0_dp
      call check_close(err, sum(lumped_mass(h%meshes(2))), 4.0_dp, 1.0e-14_dp, 0.0_dp, 'lumped mass')
      loads = assemble_loads(h%meshes(2), data)
      call check_close(err, sum(loads(:, 1)), 12.0_dp, 1.0e-14_dp, 0.0_dp, 'load 1')
      call check_close(err, sum(loads(:, 2)), -8.0_dp, 1.0e-14_dp, 0.0_dp, 'load 2')
   end subroutine test_mass_load

   !> With f = 0 and λ = 0 the interior solution of μ1 S X1 = F1 is the constant g.
   subroutine test_lifting(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      type(constant_data_t) :: data
      type(discrete_problem_t) :: p
      real(dp), allocatable :: y(:)

      call square_hierarchy(3, h, err)
      if (allocated(err)) return
      data%f1 = 0.0_dp
      data%f2 = 0.0_dp
      data%g = 0.7_dp
      data%mu1 = 2.0_dp
      call p%init(h%meshes(3), data, err)
      if (allocated(err)) return
      allocate (y(p%n))
      call p%stiffness%matvec(spread(0.7_dp, 1, p%n), y)
      call check(err, maxval(abs(2.0_dp*y - p%f(1:p%n))) < 1.0e-13_dp, 'lifting consistent with u1 = g')
   end subroutine test_lifting
end module test_assembly
