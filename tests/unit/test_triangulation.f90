!> Tests of mesh_t: orientation, derived topology, and rejection of broken connectivity.
module test_triangulation
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_triangulation

contains

   subroutine collect_triangulation(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('two_triangles_topology', test_two_triangles), &
               new_unittest('flips_clockwise', test_flips), &
               new_unittest('rejects_degenerate', test_degenerate), &
               new_unittest('rejects_nonmanifold', test_nonmanifold), &
               new_unittest('rejects_unused_vertex', test_unused), &
               new_unittest('rejects_bad_index', test_bad_index)]
   end subroutine collect_triangulation

   subroutine unit_square(mesh, err)
      type(mesh_t), intent(out) :: mesh
      type(error_t), allocatable, intent(out) :: err

      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 1.0_dp, 1.0_dp, 0.0_dp, 1.0_dp], [2, 4]), &
                     reshape([1_ip, 2_ip, 3_ip, 1_ip, 3_ip, 4_ip], [3, 2]), 'unit square', err)
   end subroutine unit_square

   subroutine test_two_triangles(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh

      call unit_square(mesh, err)
      if (allocated(err)) return
      call check(err, mesh%ne == 5, 'five edges')
      call check(err, count(mesh%boundary_edge) == 4, 'four boundary edges')
      call check(err, all(mesh%boundary_vertex), 'all vertices on the boundary')
      call check_close(err, mesh%total_area(), 1.0_dp, 4*epsilon(1.0_dp), 0.0_dp, 'area')
      call check_close(err, mesh%diameter, sqrt(2.0_dp), 4*epsilon(1.0_dp), 0.0_dp, 'diameter')
      call check(err, mesh%patch_ptr(2) - mesh%patch_ptr(1) == 2, 'vertex 1 in two triangles')
      call check(err, mesh%n_flipped == 0, 'nothing flipped')
   end subroutine test_two_triangles

   subroutine test_flips(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh

      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.0_dp, 1.0_dp], [2, 3]), &
                     reshape([1_ip, 3_ip, 2_ip], [3, 1]), 'cw', err)
      if (allocated(err)) return
      call check(err, mesh%n_flipped == 1, 'one triangle flipped')
      call check(err, all(mesh%triangles(:, 1) == [1, 2, 3]), 'now counter-clockwise')
   end subroutine test_flips

   subroutine test_degenerate(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 2.0_dp, 0.0_dp], [2, 3]), &
                     reshape([1_ip, 2_ip, 3_ip], [3, 1]), 'line', got)
      call check(err, allocated(got), 'collinear triangle rejected')
      if (allocated(got)) call check(err, index(got%message, 'zero area') > 0, 'message says zero area')
   end subroutine test_degenerate

   subroutine test_nonmanifold(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      ! three triangles on the edge (1,2)
      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.5_dp, 1.0_dp, 0.5_dp, -1.0_dp, &
                              0.5_dp, 2.0_dp], [2, 5]), &
                     reshape([1_ip, 2_ip, 3_ip, 2_ip, 1_ip, 4_ip, 1_ip, 2_ip, 5_ip], [3, 3]), 'fan', got)
      call check(err, allocated(got), 'non-manifold edge rejected')
      if (allocated(got)) call check(err, index(got%message, 'more than two') > 0, 'message names it')
   end subroutine test_nonmanifold

   subroutine test_unused(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.0_dp, 1.0_dp, 5.0_dp, 5.0_dp], [2, 4]), &
                     reshape([1_ip, 2_ip, 3_ip], [3, 1]), 'extra', got)
      call check(err, allocated(got), 'unused vertex rejected')
   end subroutine test_unused

   subroutine test_bad_index(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      call mesh%init(reshape([0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.0_dp, 1.0_dp], [2, 3]), &
                     reshape([1_ip, 2_ip, 7_ip], [3, 1]), 'bad', got)
      call check(err, allocated(got), 'out-of-range vertex rejected')
   end subroutine test_bad_index
end module test_triangulation
