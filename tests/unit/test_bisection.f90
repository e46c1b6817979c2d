!> Newest-vertex bisection: refining marked triangles keeps the mesh conforming (no hanging
!> vertex: the boundary grows only by halved boundary edges, Euler's formula holds), nested
!> (every new vertex is the midpoint of a coarse edge, every fine triangle inside a coarse one),
!> splits every marked triangle into at least four, and keeps the shapes regular through many
!> local refinements towards a corner (the smallest angle stays above a fixed bound).
module test_bisection
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t, signed_area
   use twomem_mesh_generators, only: make_square, make_disk
   use twomem_mesh_hierarchy, only: refinement_map_t
   use twomem_mesh_bisection, only: longest_edge_first, bisect_marked
   use twomem_mesh_marking, only: dorfler_marking
   use twomem_testing, only: unittest_t, new_unittest, check, check_close
   implicit none
   private

   public :: collect_bisection

contains

   subroutine collect_bisection(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('bisection_is_conforming_and_nested', test_conforming), &
               new_unittest('marked_triangles_are_refined', test_marked), &
               new_unittest('shapes_stay_regular_towards_a_corner', test_shapes), &
               new_unittest('repeated_marking_keeps_the_closure', test_repeated), &
               new_unittest('dorfler_marks_the_fewest_triangles', test_dorfler)]
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
      ! a marked triangle has its three edges halved: at least four fine triangles' centroids
      ! lie in it (more where a neighbour's closure halves a child again)
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
         refined = refined .and. inside >= 4
      end do
      call check(err, refined, 'every marked triangle is bisected three times')
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

   !> Twelve rounds of Dörfler marking on an indicator peaked at a corner and bisection of the
   !> marked set: every round's mesh is conforming (Euler characteristic 1, every interior edge
   !> shared by two triangles), counter-clockwise with positive areas, keeps its predecessor's
   !> vertices under their numbers, and covers the same area.
   subroutine test_repeated(err)
      type(error_t), allocatable, intent(out) :: err
      type(mesh_t) :: meshes(0:1)
      type(refinement_map_t) :: map
      real(dp), allocatable :: eta(:)
      real(dp) :: c(2), area0
      integer(ip) :: t
      integer :: round, now
      logical :: ok

      call start_mesh(meshes(0), err)
      if (allocated(err)) return
      area0 = meshes(0)%total_area()
      now = 0
      ok = .true.
      do round = 1, 12
         associate (m => meshes(now))
            allocate (eta(m%nt))
            do t = 1, m%nt
               c = sum(m%vertices(:, m%triangles(:, t)), dim=2)/3
               ! a singular-looking indicator: h_K times a weight that blows up at (-1, -1)
               eta(t) = sqrt(m%area(t))/(norm2(c - [-1.0_dp, -1.0_dp]) + 1.0e-3_dp)
            end do
            call bisect_marked(m, dorfler_marking(eta, 0.5_dp), meshes(1 - now), map, err)
            if (allocated(err)) return
            deallocate (eta)
            associate (f => meshes(1 - now))
               ok = ok .and. f%nv - f%ne + f%nt == 1 .and. f%n_flipped == 0 .and. all(f%area > 0.0_dp)
               ok = ok .and. count(f%edge_triangles(2, :) == 0) == count(f%boundary_edge)
               ok = ok .and. all(abs(f%vertices(:, 1:m%nv) - m%vertices) == 0.0_dp) .and. f%nv > m%nv
               ok = ok .and. abs(f%total_area() - area0) < 1.0e-12_dp
            end associate
         end associate
         now = 1 - now
      end do
      call check(err, ok, 'every round conforming, nested, oriented, area-preserving')
      call check(err, meshes(now)%nt > 4*meshes(1 - now)%nt/3, 'the rounds keep refining')
   end subroutine test_repeated

   !> Against a direct computation: sort the squares descending, take the shortest prefix whose
   !> sum reaches θ of the total. Distinct random values: the two sets coincide exactly.
   subroutine test_dorfler(err)
      type(error_t), allocatable, intent(out) :: err
      integer, parameter :: n = 500
      real(dp) :: eta(n), sorted(n), theta, partial
      logical, allocatable :: marked(:)
      integer :: i, k, j, trial
      integer, allocatable :: seed(:)

      call random_seed(size=k)
      allocate (seed(k))
      seed = 20240611
      call random_seed(put=seed)
      do trial = 1, 4
         call random_number(eta)
         eta = eta**3
         theta = 0.2_dp*trial
         marked = dorfler_marking(eta, theta)
         ! insertion sort, descending: an independent path to the answer
         sorted = eta**2
         do i = 2, n
            partial = sorted(i)
            j = i - 1
            do while (j >= 1)
               if (sorted(j) >= partial) exit
               sorted(j + 1) = sorted(j)
               j = j - 1
            end do
            sorted(j + 1) = partial
         end do
         partial = 0
         do k = 1, n
            partial = partial + sorted(k)
            if (partial >= theta*sum(eta**2)) exit
         end do
         call check(err, count(marked) == k, 'the fewest triangles are marked')
         call check(err, minval(eta**2, mask=marked) >= maxval(eta**2, mask=.not. marked), &
                    'the marked ones are the largest')
      end do
      call check(err, .not. any(dorfler_marking([0.0_dp, 0.0_dp], 0.5_dp)), 'zero indicators mark nothing')
      call check(err, all(dorfler_marking([1.0_dp, 1.0_dp, 1.0_dp], 1.0_dp)), 'theta = 1 marks everything')
   end subroutine test_dorfler
end module test_bisection
