!> Red refinement: the hierarchy conserves area and topology, is nested, and prolongs linear
!> functions exactly.
module test_refinement
   use twomem_base_kinds, only: dp, ip
   use twomem_mesh_triangulation, only: mesh_t, signed_area
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t, parent_triangle
   use twomem_fem_problem, only: constant_data_t
   use twomem_fem_discrete, only: discrete_problem_t
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_refinement, square_hierarchy, square_problem

contains

   subroutine collect_refinement(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('area_and_euler', test_area_euler), &
               new_unittest('nested_children', test_nested), &
               new_unittest('prolongation_exact_for_linear', test_prolong), &
               new_unittest('boundary_stays_on_coarse_edges', test_boundary), &
               new_unittest('whole_meshes_number_themselves', test_whole_numbering)]
   end subroutine collect_refinement

   !> Every level refined from a whole mesh is whole: no numbering of a piece is stored, its
   !> global numbers are its own and every owner is rank 0; the diameters are the longest edges.
   subroutine test_whole_numbering(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      integer(ip) :: a, t
      integer :: l
      character(len=48) :: msg

      call square_hierarchy(2, h, err)
      if (allocated(err)) return
      do l = 0, 2
         associate (m => h%meshes(l))
            write (msg, '("level ",i0)') l
            call check(err, m%whole() .and. .not. allocated(m%global_vertex) .and. &
                       .not. allocated(m%triangle_owner), 'whole, nothing stored: '//trim(msg))
            call check(err, m%nv_global == m%nv .and. m%nt_global == m%nt .and. m%nt_owned == m%nt, &
                       'whole sizes: '//trim(msg))
            call check(err, all(m%global_vertex_of([(a, a=1, m%nv)]) == [(a, a=1, m%nv)]) .and. &
                       all(m%global_triangle_of([(t, t=1, m%nt)]) == [(t, t=1, m%nt)]) .and. &
                       all(m%vertex_owner_of([(a, a=1, m%nv)]) == 0) .and. &
                       all(m%triangle_owner_of([(t, t=1, m%nt)]) == 0), 'own numbers, rank 0: '//trim(msg))
            ! every level-l triangle of the square is right isosceles with hypotenuse 2^(1−l)
            call check_close(err, maxval(m%diameter_of([(t, t=1, m%nt)])), 2.0_dp**(1 - l), 1.0e-14_dp, 0.0_dp, &
                             'longest edge: '//trim(msg))
            call check_close(err, minval(m%diameter_of([(t, t=1, m%nt)])), 2.0_dp**(1 - l), 1.0e-14_dp, 0.0_dp, &
                             'every triangle alike: '//trim(msg))
         end associate
         if (allocated(err)) return
      end do
   end subroutine test_whole_numbering

   !> (-1,1)² from four triangles around the centre, refined `levels` times.
   subroutine square_hierarchy(levels, h, err)
      integer, intent(in) :: levels
      type(mesh_hierarchy_t), intent(out) :: h
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: coarse

      call coarse%init(reshape([-1.0_dp, -1.0_dp, 1.0_dp, -1.0_dp, 1.0_dp, 1.0_dp, -1.0_dp, 1.0_dp, &
                                0.0_dp, 0.0_dp], [2, 5]), &
                       reshape([1_ip, 2_ip, 5_ip, 2_ip, 3_ip, 5_ip, 3_ip, 4_ip, 5_ip, 4_ip, 1_ip, 5_ip], &
                               [3, 4]), 'square', err)
      if (allocated(err)) return
      call h%init(coarse, levels, err)
   end subroutine square_hierarchy

   !> The discrete problem on the square refined `levels` times, with constant data and
   !> unequal tensions (μ1 = 1, μ2 = 2 unless given), so the two membrane blocks differ: the
   !> fixture of the Newton, preconditioner and multigrid suites.
   subroutine square_problem(levels, h, p, err, mu2)
      integer, intent(in) :: levels
      type(mesh_hierarchy_t), intent(out) :: h
      type(discrete_problem_t), intent(out) :: p
      type(error_t), allocatable, intent(out) :: err
      real(dp), intent(in), optional :: mu2

      type(constant_data_t) :: data

      call square_hierarchy(levels, h, err)
      if (allocated(err)) return
      data%mu1 = 1.0_dp
      data%mu2 = 2.0_dp
      if (present(mu2)) data%mu2 = mu2
      call p%init(h%meshes(levels), data, err)
   end subroutine square_problem

   subroutine test_area_euler(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      integer :: l

      call square_hierarchy(4, h, err)
      if (allocated(err)) return
      do l = 0, 4
         associate (m => h%meshes(l))
            call check_close(err, m%total_area(), 4.0_dp, 64*epsilon(1.0_dp), 0.0_dp, 'area')
            call check(err, m%nv - m%ne + m%nt == 1, 'Euler characteristic 1')
            call check(err, m%nt == 4*4**l, 'four children per triangle')
            call check(err, m%n_flipped == 0, 'children are counter-clockwise')
            call check_close(err, m%diameter, sqrt(8.0_dp), 4*epsilon(1.0_dp), 0.0_dp, 'diameter kept')
         end associate
      end do
   end subroutine test_area_euler

   subroutine test_nested(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      integer(ip) :: t, parent, i
      real(dp) :: x(2), lam(3)

      call square_hierarchy(3, h, err)
      if (allocated(err)) return
      associate (fine => h%meshes(3), coarse => h%meshes(2))
         do t = 1, fine%nt
            parent = parent_triangle(t)
            ! every fine vertex lies in the closed parent triangle (barycentric coordinates ≥ 0)
            do i = 1, 3
               x = fine%vertices(:, fine%triangles(i, t))
               associate (p => coarse%vertices(:, coarse%triangles(:, parent)))
                  lam = [signed_area(x, p(:, 2), p(:, 3)), signed_area(p(:, 1), x, p(:, 3)), &
                         signed_area(p(:, 1), p(:, 2), x)]/coarse%area(parent)
               end associate
               call check(err, all(lam >= -1.0e-14_dp), 'fine triangle inside its parent')
            end do
         end do
         call check_close(err, sum(fine%area), sum(coarse%area), 1.0e-14_dp, 0.0_dp, 'area kept')
      end associate
   end subroutine test_nested

   subroutine test_prolong(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      real(dp), allocatable :: uc(:), uf(:)

      call square_hierarchy(2, h, err)
      if (allocated(err)) return
      uc = 0.3_dp + 2*h%meshes(1)%vertices(1, :) - 0.7_dp*h%meshes(1)%vertices(2, :)
      allocate (uf(h%meshes(2)%nv))
      call h%prolong(2, uc, uf)
      call check(err, maxval(abs(uf - (0.3_dp + 2*h%meshes(2)%vertices(1, :) - &
                                       0.7_dp*h%meshes(2)%vertices(2, :)))) < 1.0e-14_dp, &
                 'linear function interpolated exactly')
   end subroutine test_prolong

   subroutine test_boundary(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_hierarchy_t) :: h
      integer(ip) :: a

      call square_hierarchy(3, h, err)
      if (allocated(err)) return
      call check(err, h%meshes(3)%n_boundary_vertices() == 2**3*h%meshes(0)%n_boundary_vertices(), &
                 'boundary vertices double per level')
      do a = 1, h%meshes(3)%nv
         if (h%meshes(3)%boundary_vertex(a)) then
            call check(err, maxval(abs(h%meshes(3)%vertices(:, a))) > 1 - 1.0e-14_dp, &
                       'boundary vertex on the square boundary')
         end if
      end do
   end subroutine test_boundary
end module test_refinement
