!> Tests of the built-in meshes: the disk's boundary lies on the circle with the asked spacing,
!> its triangles are well shaped and sized, the grading is gentle, and the square has the counts
!> and symmetry it promises; bad sizes come back as errors.
module test_generators
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_positive_inf
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: exit_bad_input
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_generators, only: make_disk, make_square, disk_boundary_spacing, c_geo
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_generators

   real(dp), parameter :: pi = 4*atan(1.0_dp)
   !> (coarse_h, boundary_h) pairs: uniform ones, the paper's sizes, and graded ones
   integer, parameter :: n_cases = 8
   real(dp), parameter :: cases(2, n_cases) = reshape([ &
                                                      0.25_dp, 0.25_dp, 0.12_dp, 0.12_dp, 0.06_dp, 0.06_dp, &
                                                      0.7_dp, 0.7_dp, 0.25_dp, 0.05_dp, 0.125_dp, 0.02_dp, &
                                                      0.1_dp, 0.01_dp, 0.05_dp, 0.002_dp], [2, n_cases])

contains

   subroutine collect_generators(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('disk_boundary_on_circle', test_disk_on_circle), &
               new_unittest('disk_boundary_spacing', test_disk_spacing), &
               new_unittest('disk_area_is_inscribed_polygon', test_disk_area), &
               new_unittest('disk_shape_and_size', test_disk_shape), &
               new_unittest('disk_euler_characteristic', test_disk_euler), &
               new_unittest('disk_triangle_count', test_disk_count), &
               new_unittest('disk_grading_gentle', test_disk_grading), &
               new_unittest('disk_deterministic', test_disk_deterministic), &
               new_unittest('disk_rejects_bad_sizes', test_disk_rejects), &
               new_unittest('square_counts_and_area', test_square), &
               new_unittest('square_checkerboard', test_square_checkerboard), &
               new_unittest('square_rejects_bad_sizes', test_square_rejects), &
               new_unittest('boundary_spacing_rule', test_spacing_rule)]
   end subroutine collect_generators

   subroutine disk(c, mesh, err)
      integer, intent(in) :: c
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err

      call make_disk(cases(1, c), cases(2, c), mesh, err)
      if (allocated(err)) err%message = 'make_disk failed: '//err%message
   end subroutine disk

   !> Smallest angle of the mesh in degrees.
   real(dp) function min_angle(mesh)
      type(mesh_t), intent(in) :: mesh

      integer(ip) :: t, i
      real(dp) :: e(2, 3)

      min_angle = 180.0_dp
      do t = 1, mesh%nt
         do i = 1, 3
            e(:, i) = mesh%vertices(:, mesh%triangles(mod(i, 3) + 1, t)) &
                      - mesh%vertices(:, mesh%triangles(i, t))
         end do
         do i = 1, 3
            ! angle between the edge leaving a vertex and the reversed edge arriving at it
            min_angle = min(min_angle, acos(-dot_product(e(:, i), e(:, mod(i + 1, 3) + 1)) &
                                            /(norm2(e(:, i))*norm2(e(:, mod(i + 1, 3) + 1))))*180/pi)
         end do
      end do
   end function min_angle

   real(dp) function edge_length(mesh, e)
      type(mesh_t), intent(in) :: mesh
      integer(ip), intent(in) :: e

      edge_length = norm2(mesh%vertices(:, mesh%edges(2, e)) - mesh%vertices(:, mesh%edges(1, e)))
   end function edge_length

   subroutine test_disk_on_circle(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c
      integer(ip) :: a
      real(dp) :: worst

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         worst = 0.0_dp
         do a = 1, mesh%nv
            if (mesh%boundary_vertex(a)) worst = max(worst, abs(norm2(mesh%vertices(:, a)) - 1.0_dp))
         end do
         call check(err, worst <= 1.0e-14_dp, 'a boundary vertex is off the unit circle')
         call check(err, all(sum(mesh%vertices**2, dim=1) <= 1.0_dp + 1.0e-14_dp), &
                    'a vertex lies outside the unit disk')
         call check(err, mesh%n_flipped == 0, 'the generator emitted a clockwise triangle')
         if (allocated(err)) return
      end do
   end subroutine test_disk_on_circle

   subroutine test_disk_spacing(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c
      integer(ip) :: e
      real(dp) :: expected, l

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         expected = 2*pi/cases(2, c)
         call check_close(err, real(mesh%n_boundary_vertices(), dp), expected, 0.15_dp, 0.0_dp, &
                          'number of boundary vertices')
         do e = 1, mesh%ne
            if (.not. mesh%boundary_edge(e)) cycle
            l = edge_length(mesh, e)
            call check(err, abs(l - cases(2, c)) <= 0.15_dp*cases(2, c), &
                       'a boundary edge is not about the boundary spacing long')
         end do
         if (allocated(err)) return
      end do
   end subroutine test_disk_spacing

   !> The mesh must cover exactly the polygon inscribed through its boundary vertices:
   !> Σ ½ sin Δθ over the gaps between consecutive boundary angles.
   subroutine test_disk_area(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c
      integer(ip) :: a, i, j, nb
      real(dp), allocatable :: theta(:)
      real(dp) :: key, polygon

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         theta = pack([(atan2(mesh%vertices(2, a), mesh%vertices(1, a)), a=1, mesh%nv)], &
                      mesh%boundary_vertex)
         nb = int(size(theta), ip)
         ! insertion sort: a few thousand angles at most, already nearly sorted
         do i = 2, nb
            key = theta(i)
            j = i - 1
            do while (j >= 1)
               if (theta(j) <= key) exit
               theta(j + 1) = theta(j)
               j = j - 1
            end do
            theta(j + 1) = key
         end do
         polygon = 0.5_dp*sin(theta(1) + 2*pi - theta(nb))
         do i = 2, nb
            polygon = polygon + 0.5_dp*sin(theta(i) - theta(i - 1))
         end do
         call check_close(err, mesh%total_area(), polygon, 1.0e-12_dp, 0.0_dp, 'mesh area')
         if (allocated(err)) return
      end do
   end subroutine test_disk_area

   subroutine test_disk_shape(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c
      integer(ip) :: it
      character(len=80) :: msg

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         write (msg, '(a,f6.2)') 'smallest angle below 20 degrees: ', min_angle(mesh)
         call check(err, min_angle(mesh) >= 20.0_dp, trim(msg))
         write (msg, '(a,f6.3)') 'longest edge / coarse_h above 1.5: ', maxval(mesh%diameter_of([(it, it=1, mesh%nt)]))/cases(1, c)
         call check(err, maxval(mesh%diameter_of([(it, it=1, mesh%nt)])) <= 1.5_dp*cases(1, c), trim(msg))
         if (allocated(err)) return
      end do
   end subroutine test_disk_shape

   subroutine test_disk_euler(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         call check(err, mesh%nv - mesh%ne + mesh%nt == 1, 'V - E + T /= 1: not a disk')
         call check(err, count(mesh%boundary_edge) == mesh%n_boundary_vertices(), &
                    'the boundary is not a single closed polygon')
         if (allocated(err)) return
      end do
   end subroutine test_disk_euler

   !> With no grading the triangles should be near-equilateral of side coarse_h.
   subroutine test_disk_count(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: k
      real(dp), parameter :: sizes(4) = [0.25_dp, 0.12_dp, 0.06_dp, 0.02_dp]

      do k = 1, size(sizes)
         call make_disk(sizes(k), sizes(k), mesh, err)
         if (allocated(err)) return
         call check_close(err, real(mesh%nt, dp), pi/(sqrt(3.0_dp)/4*sizes(k)**2), 0.25_dp, 0.0_dp, &
                          'triangle count of the uniform disk')
         if (allocated(err)) return
      end do
   end subroutine test_disk_count

   !> Neighbouring triangles differ in size by no more than the grading allows (~1.3, plus
   !> the rounding of ring counts), and the band costs far fewer triangles than a uniform
   !> mesh at the boundary spacing would.
   subroutine test_disk_grading(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: c
      integer(ip) :: e
      real(dp) :: ratio, worst

      do c = 1, n_cases
         call disk(c, mesh, err)
         if (allocated(err)) return
         worst = 1.0_dp
         do e = 1, mesh%ne
            if (mesh%boundary_edge(e)) cycle
            ratio = mesh%area(mesh%edge_triangles(1, e))/mesh%area(mesh%edge_triangles(2, e))
            worst = max(worst, sqrt(max(ratio, 1.0_dp/ratio)))
         end do
         call check(err, worst <= 1.35_dp, 'neighbouring triangle sizes differ by more than 1.35')
         if (cases(2, c) < 0.5_dp*cases(1, c)) then
            call check(err, real(mesh%nt, dp) < 0.25_dp*pi/(sqrt(3.0_dp)/4*cases(2, c)**2), &
                       'the graded band is too wide')
         end if
         if (allocated(err)) return
      end do
   end subroutine test_disk_grading

   subroutine test_disk_deterministic(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: first, second

      call make_disk(0.1_dp, 0.03_dp, first, err)
      if (allocated(err)) return
      call make_disk(0.1_dp, 0.03_dp, second, err)
      if (allocated(err)) return
      call check(err, first%nv == second%nv .and. first%nt == second%nt, 'counts differ between calls')
      if (allocated(err)) return
      call check(err, all(first%vertices == second%vertices), 'coordinates differ between calls')
      call check(err, all(first%triangles == second%triangles), 'connectivity differs between calls')
   end subroutine test_disk_deterministic

   subroutine test_disk_rejects(err)
      type(error_t), allocatable, intent(out) :: err

      call expect_disk_error(err, 0.0_dp, 0.0_dp, 'zero size')
      call expect_disk_error(err, -0.1_dp, -0.1_dp, 'negative size')
      call expect_disk_error(err, 0.1_dp, 0.0_dp, 'zero boundary spacing')
      call expect_disk_error(err, 0.1_dp, -0.01_dp, 'negative boundary spacing')
      call expect_disk_error(err, 0.1_dp, 0.2_dp, 'boundary spacing above the size')
      call expect_disk_error(err, ieee_value(1.0_dp, ieee_positive_inf), 0.1_dp, 'infinite size')
      call expect_disk_error(err, 1.0e-4_dp, 1.0e-4_dp, 'too many triangles inside')
      call expect_disk_error(err, 0.1_dp, 1.0e-9_dp, 'too many boundary vertices')
      call expect_disk_error(err, 0.2_dp, 2.0e-7_dp, 'too many triangles in the band')
   end subroutine test_disk_rejects

   subroutine expect_disk_error(err, coarse_h, boundary_h, what)
      type(error_t), allocatable, intent(inout) :: err
      real(dp), intent(in) :: coarse_h, boundary_h
      character(len=*), intent(in) :: what

      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      call make_disk(coarse_h, boundary_h, mesh, got)
      call check(err, allocated(got), 'make_disk accepted '//what)
      if (allocated(got)) call check(err, got%code == exit_bad_input, 'wrong error code for '//what)
      call check(err, mesh%nt == 0, 'make_disk left a mesh behind after '//what)
   end subroutine expect_disk_error

   subroutine test_square(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer :: k
      integer(ip) :: n, it
      real(dp), parameter :: sizes(3) = [2.0_dp, 0.3_dp, 0.05_dp]

      do k = 1, size(sizes)
         call make_square(sizes(k), mesh, err)
         if (allocated(err)) return
         n = int(ceiling(2/sizes(k)), ip)
         call check(err, mesh%nv == (n + 1)**2, 'square vertex count')
         call check(err, mesh%nt == 2*n**2, 'square triangle count')
         call check(err, mesh%n_boundary_vertices() == 4*n, 'square boundary vertex count')
         call check_close(err, mesh%total_area(), 4.0_dp, mesh%nt*epsilon(1.0_dp), 0.0_dp, 'square area')
         call check(err, all(abs(mesh%vertices) <= 1.0_dp), 'a vertex outside the square')
         call check(err, min_angle(mesh) >= 45.0_dp - 1.0e-10_dp, 'square angles are not 45/90')
         call check(err, maxval(mesh%diameter_of([(it, it=1, mesh%nt)])) <= sqrt(2.0_dp)*sizes(k)*(1 + 1.0e-12_dp), &
                    'square cells larger than coarse_h')
         if (allocated(err)) return
      end do
   end subroutine test_square

   !> As many diagonals lean one way as the other (exactly, for an even number of cells).
   subroutine test_square_checkerboard(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      integer(ip) :: e, rising, falling
      real(dp) :: d(2)

      call make_square(0.25_dp, mesh, err)
      if (allocated(err)) return
      rising = 0
      falling = 0
      do e = 1, mesh%ne
         d = mesh%vertices(:, mesh%edges(2, e)) - mesh%vertices(:, mesh%edges(1, e))
         if (abs(d(1)) < 1.0e-12_dp .or. abs(d(2)) < 1.0e-12_dp) cycle
         if (d(1)*d(2) > 0.0_dp) then
            rising = rising + 1
         else
            falling = falling + 1
         end if
      end do
      call check(err, rising + falling == 64, 'one diagonal per cell')
      call check(err, rising == falling, 'diagonals do not alternate')
   end subroutine test_square_checkerboard

   subroutine test_square_rejects(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got

      call make_square(0.0_dp, mesh, got)
      call check(err, allocated(got), 'make_square accepted a zero size')
      if (allocated(got)) deallocate (got)
      call make_square(-1.0_dp, mesh, got)
      call check(err, allocated(got), 'make_square accepted a negative size')
      if (allocated(got)) deallocate (got)
      call make_square(1.0e-4_dp, mesh, got)
      call check(err, allocated(got), 'make_square accepted 8e8 triangles')
      if (allocated(got)) call check(err, got%code == exit_bad_input, 'wrong error code')
   end subroutine test_square_rejects

   subroutine test_spacing_rule(err)
      type(error_t), allocatable, intent(out) :: err
      integer :: levels
      real(dp) :: s, previous

      call check_close(err, disk_boundary_spacing(0.25_dp, 0), 0.25_dp, 0.0_dp, 0.0_dp, &
                       'no refinement: the coarse size suffices')
      previous = 0.25_dp
      do levels = 1, 6
         s = disk_boundary_spacing(0.25_dp, levels)
         call check(err, s <= previous, 'spacing shrinks with the number of levels')
         call check_close(err, s, 0.25_dp*min(1.0_dp, c_geo*2.0_dp**(-2*levels/3.0_dp)), &
                          4*epsilon(1.0_dp), 0.0_dp, 'spacing rule')
         ! self-similar: halving coarse_h halves the spacing
         call check_close(err, disk_boundary_spacing(0.125_dp, levels), s/2, 4*epsilon(1.0_dp), 0.0_dp, &
                          'spacing proportional to coarse_h')
         previous = s
      end do
      ! One more level divides the spacing by 2^(2/3).
      call check_close(err, disk_boundary_spacing(0.25_dp, 5)/disk_boundary_spacing(0.25_dp, 6), &
                       2.0_dp**(2.0_dp/3), 8*epsilon(1.0_dp), 0.0_dp, 'rate of the spacing rule')
   end subroutine test_spacing_rule
end module test_generators
