!> Newest-vertex bisection: refining marked triangles keeps the mesh conforming (no hanging
!> vertex: the boundary grows only by halved boundary edges, Euler's formula holds), nested
!> (every new vertex is the midpoint of a coarse edge, every fine triangle inside a coarse one),
!> refines every marked triangle, and keeps the shapes regular through many local refinements
!> towards a corner (the smallest angle stays above a fixed bound).
module test_bisection
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t, signed_area
   use twomem_mesh_generators, only: make_square, make_disk
   use twomem_mesh_hierarchy, only: refinement_map_t
   use twomem_mesh_bisection, only: longest_edge_first, bisect_marked
   use twomem_testing, only: unittest_t, new_unittest, check, check_close
   implicit none
   private

   public :: collect_bisection

contains

   subroutine collect_bisection(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('bisection_is_conforming_and_nested', test_conforming), &
               new_unittest('marked_triangles_are_refined', test_marked), &
               new_unittest('shapes_stay_regular_towards_a_corner', test_shapes)]
   end subroutine collect_bisection

   subroutine start_mesh(mesh, err)
      type(mesh_t), intent(out) :: mesh
      type(error_t), allocatable, intent(out) :: err

      call make_square(0.5_dp, mesh, err)
      if (allocated(err)) return
      call longest_edge_first(mesh, err)
   end subroutine start_mesh

   !> Smallest angle (radians) of the mesh's triangles.
   real(dp) function smallest_angle(mesh) result(angle)
      type(mesh_t), intent(in) :: mesh

      integer(ip) :: t
      integer :: i
      real(dp) :: a(2), b(2)

      angle = huge(1.0_dp)
      do t = 1, mesh%nt
         do i = 1, 3
            a = mesh%vertices(:, mesh%triangles(mod(i, 3) + 1, t)) - mesh%vertices(:, mesh%triangles(i, t))
            b = mesh%vertices(:, mesh%triangles(mod(i + 1, 3) + 1, t)) - mesh%vertices(:, mesh%triangles(i, t))
            angle = min(angle, acos(max(-1.0_dp, min(1.0_dp, dot_product(a, b)/(norm2(a)*norm2(b))))))
         end do
      end do
   end function smallest_angle

   subroutine test_conforming(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: coarse, fine
      type(refinement_map_t) :: map
      logical, allocatable :: marked(:)
      integer(ip) :: t, a, n_boundary_halved, e
      real(dp) :: mid(2), c(2), bary(3), area
      logical :: nested, inside

      call start_mesh(coarse, err)
      if (allocated(err)) return
      allocate (marked(coarse%nt))
      ! a few scattered triangles
      marked = [(mod(t, 7_ip) == 0, t=1, coarse%nt)]
      call bisect_marked(coarse, marked, fine, map, err)
      if (allocated(err)) return
      call check(err, fine%n_flipped == 0, 'children are counter-clockwise')
      call check_close(err, fine%total_area(), coarse%total_area(), 1.0e-13_dp, 0.0_dp, 'the area is kept')
      call check(err, fine%nv - fine%ne + fine%nt == 1, 'Euler characteristic 1: no hanging vertex')
      n_boundary_halved = 0
      do e = 1, coarse%ne
         if (.not. coarse%boundary_edge(e)) cycle
         mid = 0.5_dp*(coarse%vertices(:, coarse%edges(1, e)) + coarse%vertices(:, coarse%edges(2, e)))
         if (any(all(abs(fine%vertices - spread(mid, 2, fine%nv)) < 1.0e-14_dp, dim=1))) &
            n_boundary_halved = n_boundary_halved + 1
      end do
      call check(err, count(fine%boundary_edge) == count(coarse%boundary_edge) + n_boundary_halved, &
                 'the boundary grows only by halved boundary edges')
      nested = all(map%vertex_parents(:, 1:coarse%nv) == spread([(a, a=1, coarse%nv)], 1, 2))
      do a = coarse%nv + 1, fine%nv
         nested = nested .and. all(abs(fine%vertices(:, a) - 0.5_dp*(coarse%vertices(:, map%vertex_parents(1, a)) + &
                                                                       coarse%vertices(:, map%vertex_parents(2, a)))) &
                                   < 1.0e-15_dp)
      end do
      call check(err, nested, 'old vertices keep their numbers, new ones are edge midpoints')
      ! every fine triangle's centroid lies in a coarse triangle that holds the whole fine one
      nested = .true.
      do t = 1, fine%nt
         c = sum(fine%vertices(:, fine%triangles(:, t)), dim=2)/3
         inside = .false.
         do a = 1, coarse%nt
            associate (p => coarse%vertices(:, coarse%triangles(:, a)))
               area = signed_area(p(:, 1), p(:, 2), p(:, 3))
               bary = [signed_area(c, p(:, 2), p(:, 3)), signed_area(p(:, 1), c, p(:, 3)), &
                       signed_area(p(:, 1), p(:, 2), c)]/area
            end associate
            if (all(bary > 0.0_dp)) then
               inside = fine%area(t) <= coarse%area(a)*(1 + 1.0e-12_dp)
               exit
            end if
         end do
         nested = nested .and. inside
      end do
      call check(err, nested, 'every fine triangle lies in a coarse one')
   end subroutine test_conforming

   subroutine test_marked(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: coarse, fine
      type(refinement_map_t) :: map
      logical, allocatable :: marked(:)
      integer(ip) :: t, k, inside
      real(dp) :: c(2)
      logical :: refined

      call start_mesh(coarse, err)
      if (allocated(err)) return
      allocate (marked(coarse%nt))
      marked = .false.
      marked(1:coarse%nt:5) = .true.
      call bisect_marked(coarse, marked, fine, map, err)
      if (allocated(err)) return
      ! a marked triangle contains at least two fine triangles' centroids
      refined = .true.
      do t = 1, coarse%nt
         if (.not. marked(t)) cycle
         inside = 0
         do k = 1, fine%nt
            c = sum(fine%vertices(:, fine%triangles(:, k)), dim=2)/3
            associate (p => coarse%vertices(:, coarse%triangles(:, t)))
               if (signed_area(c, p(:, 2), p(:, 3)) > 0 .and. signed_area(p(:, 1), c, p(:, 3)) > 0 .and. &
                   signed_area(p(:, 1), p(:, 2), c) > 0) inside = inside + 1
            end associate
         end do
         refined = refined .and. inside >= 2
      end do
      call check(err, refined, 'every marked triangle is bisected')
      call check(err, fine%nt > coarse%nt + count(marked), 'the closure refines neighbours too')
   end subroutine test_marked

   subroutine test_shapes(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: meshes(0:1)
      type(refinement_map_t) :: map
      logical, allocatable :: marked(:)
      real(dp) :: start_angle, worst, corner(2)
      integer(ip) :: t, nt_start
      integer :: step, now

      ! an unstructured start: the built-in disk
      call make_disk(0.4_dp, 0.4_dp, meshes(0), err)
      if (allocated(err)) return
      call longest_edge_first(meshes(0), err)
      if (allocated(err)) return
      start_angle = smallest_angle(meshes(0))
      nt_start = meshes(0)%nt
      corner = meshes(0)%vertices(:, minloc(norm2(meshes(0)%vertices - spread([1.0_dp, 0.0_dp], 2, meshes(0)%nv), &
                                                    dim=1), dim=1))
      worst = start_angle
      now = 0
      ! 24 steps refining every triangle at a boundary vertex: a mesh graded towards it
      do step = 1, 24
         allocate (marked(meshes(now)%nt))
         do t = 1, meshes(now)%nt
            marked(t) = any(norm2(meshes(now)%vertices(:, meshes(now)%triangles(:, t)) - spread(corner, 2, 3), &
                                  dim=1) < 1.0e-12_dp)
         end do
         call bisect_marked(meshes(now), marked, meshes(1 - now), map, err)
         if (allocated(err)) return
         deallocate (marked)
         now = 1 - now
         worst = min(worst, smallest_angle(meshes(now)))
      end do
      call check(err, meshes(now)%nt > nt_start + 60, 'the vertex was refined towards')
      ! newest-vertex bisection makes finitely many similarity classes per initial triangle
      call check(err, worst >= 0.5_dp*start_angle, 'the smallest angle stays above half the initial one')
   end subroutine test_shapes
end module test_bisection
