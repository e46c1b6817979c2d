!> Tests of the Gmsh reader: meshes written by Gmsh itself in MSH 2.2 and 4.1 (counts as written
!> by scripts/make_gmsh_meshes.py), hand-written files with sparse tags, CRLF and clockwise
!> triangles, and one broken file per defect, each of which must come back as an error naming the
!> file (and the line, where there is one) rather than a crash.
module test_gmsh
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: exit_bad_input
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_gmsh, only: read_gmsh
   use twomem_base_text, only: int_text
   use twomem_testing, only: unittest_t, new_unittest, check, check_close, error_t
   implicit none
   private

   public :: collect_gmsh

   !> distance within which a vertex counts as lying on a straight piece of the boundary
   real(dp), parameter :: on_line = 1.0e-12_dp

contains

   subroutine collect_gmsh(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('square_msh22', test_square_22), &
               new_unittest('square_msh22_groups', test_square_22_groups), &
               new_unittest('square_msh41', test_square_41), &
               new_unittest('square_msh41_groups', test_square_41_groups), &
               new_unittest('same_mesh_both_versions', test_same_mesh), &
               new_unittest('lshape_msh41', test_lshape), &
               new_unittest('sparse_tags_crlf', test_sparse), &
               new_unittest('flips_clockwise', test_clockwise), &
               new_unittest('drops_unused_nodes', test_unused_nodes), &
               new_unittest('rejects_broken_files', test_broken), &
               new_unittest('rejects_missing_file', test_missing), &
               new_unittest('huge_coordinates', test_huge), &
               new_unittest('number_forms', test_number_forms), &
               new_unittest('renumbers_a_large_mesh', test_renumbered)]
   end subroutine collect_gmsh

   !> Path of a file under tests/data/meshes.
   subroutine data_file(name, path, err)
      character(len=*), intent(in) :: name
      character(len=:), allocatable, intent(out) :: path
      type(error_t), allocatable, intent(out) :: err

      character(len=4096) :: root
      integer :: length, status

      call get_environment_variable('TWOMEM_TEST_DATA', root, length, status)
      call check(err, status == 0 .and. length > 0, &
                 'TWOMEM_TEST_DATA is not set (run through ctest)')
      if (allocated(err)) return
      path = root(1:length)//'/meshes/'//name
   end subroutine data_file

   subroutine read_data(name, mesh, err)
      character(len=*), intent(in) :: name
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: path

      call data_file(name, path, err)
      if (allocated(err)) return
      call read_gmsh(path, mesh, err)
   end subroutine read_data

   !> Counts, area and boundary of the Gmsh square (-1,1)^2; the boundary that mesh_t finds must
   !> be exactly the vertices on the four sides, and it is one closed loop (Euler characteristic 1).
   subroutine check_square(name, err)
      character(len=*), intent(in) :: name
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      integer(ip) :: on_sides

      call read_data(name, mesh, err)
      if (allocated(err)) return
      call check(err, mesh%nv == 30, name//': 30 nodes as in $Nodes')
      call check(err, mesh%nt == 42, name//': 42 triangles (type 2) as in $Elements')
      call check_close(err, mesh%total_area(), 4.0_dp, 16*epsilon(1.0_dp), 0.0_dp, name//': area')
      on_sides = int(count(maxval(abs(mesh%vertices), dim=1) >= 1.0_dp - on_line), ip)
      call check(err, mesh%n_boundary_vertices() == on_sides, &
                 name//': boundary vertices are those on the sides')
      call check(err, count(mesh%boundary_edge) == on_sides, name//': boundary is one closed loop')
      call check(err, mesh%nv - mesh%ne + mesh%nt == 1, name//': Euler characteristic of a disk')
   end subroutine check_square

   subroutine test_square_22(err)
      type(error_t), allocatable, intent(out) :: err

      call check_square('square_msh22.msh', err)
   end subroutine test_square_22

   subroutine test_square_22_groups(err)
      type(error_t), allocatable, intent(out) :: err

      call check_square('square_msh22_groups.msh', err)
   end subroutine test_square_22_groups

   subroutine test_square_41(err)
      type(error_t), allocatable, intent(out) :: err

      call check_square('square_msh41.msh', err)
   end subroutine test_square_41

   subroutine test_square_41_groups(err)
      type(error_t), allocatable, intent(out) :: err

      call check_square('square_msh41_groups.msh', err)
   end subroutine test_square_41_groups

   !> Gmsh writes one mesh in both formats; node order is file order, so both readers must agree
   !> vertex by vertex and triangle by triangle.
   subroutine test_same_mesh(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: m22, m41

      call read_data('square_msh22.msh', m22, err)
      if (allocated(err)) return
      call read_data('square_msh41.msh', m41, err)
      if (allocated(err)) return
      call check(err, all(m22%vertices == m41%vertices), 'same vertices in MSH 2.2 and 4.1')
      call check(err, all(m22%triangles == m41%triangles), 'same triangles in MSH 2.2 and 4.1')
   end subroutine test_same_mesh

   !> The L-shape (-1,1)^2 \ [0,1)x(-1,0]: area 3, and the boundary vertices are exactly those on
   !> its six sides, including the re-entrant corner.
   subroutine test_lshape(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      integer(ip) :: a, on_sides
      logical :: corner

      call read_data('lshape_msh41.msh', mesh, err)
      if (allocated(err)) return
      call check(err, mesh%nv == 202, '202 nodes as in $Nodes')
      call check(err, mesh%nt == 346, '346 triangles as in $Elements')
      call check_close(err, mesh%total_area(), 3.0_dp, 16*epsilon(1.0_dp), 0.0_dp, 'area')
      on_sides = 0
      corner = .false.
      do a = 1, mesh%nv
         associate (x => mesh%vertices(1, a), y => mesh%vertices(2, a))
            if (on_l_boundary(x, y)) on_sides = on_sides + 1
            if (abs(x) < on_line .and. abs(y) < on_line) corner = mesh%boundary_vertex(a)
         end associate
      end do
      call check(err, mesh%n_boundary_vertices() == on_sides, 'boundary vertices on the six sides')
      call check(err, count(mesh%boundary_edge) == on_sides, 'boundary is one closed loop')
      call check(err, corner, 're-entrant corner is a boundary vertex')
      call check(err, mesh%nv - mesh%ne + mesh%nt == 1, 'Euler characteristic of a disk')
   end subroutine test_lshape

   pure logical function on_l_boundary(x, y)
      real(dp), intent(in) :: x, y

      on_l_boundary = abs(x + 1) < on_line .or. abs(y - 1) < on_line &
                      .or. (abs(y + 1) < on_line .and. x <= on_line) &
                      .or. (abs(x) < on_line .and. y <= on_line) &
                      .or. (abs(y) < on_line .and. x >= -on_line) &
                      .or. (abs(x - 1) < on_line .and. y >= -on_line)
   end function on_l_boundary

   !> Node tags 1000, 7, 42, 5, 300 in three entity blocks (one parametric), CRLF line ends, tabs
   !> and a blank line: vertices are numbered in file order whatever the tags.
   subroutine test_sparse(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh

      call read_data('sparse_crlf.msh', mesh, err)
      if (allocated(err)) return
      call check(err, mesh%nv == 5 .and. mesh%nt == 4, 'five nodes, four triangles')
      call check(err, all(mesh%vertices(:, 1) == [0.0_dp, 0.0_dp]), 'tag 1000 is vertex 1')
      call check(err, all(mesh%vertices(:, 3) == [2.0_dp, 1.0_dp]), &
                 'tag 42 (parametric) is vertex 3')
      call check(err, all(mesh%vertices(:, 5) == [1.0_dp, 0.5_dp]), 'tag 300 is vertex 5')
      call check(err, all(mesh%triangles(:, 1) == [1, 2, 5]), 'triangle 100 is (1000, 7, 300)')
      call check(err, all(mesh%triangles(:, 4) == [4, 1, 5]), 'triangle 999 is (5, 1000, 300)')
      call check_close(err, mesh%total_area(), 2.0_dp, 4*epsilon(1.0_dp), 0.0_dp, 'area')
      call check(err, mesh%n_boundary_vertices() == 4, 'four corners on the boundary')
   end subroutine test_sparse

   !> As Gmsh's built-in kernel writes files: nodes no triangle uses (geometry points), point and
   !> line elements, elements without physical tags. The unused nodes are dropped, the others
   !> keep the file's order.
   subroutine test_unused_nodes(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      character(len=:), allocatable :: path
      integer(ip) :: n_unused

      call data_file('unused_nodes.msh', path, err)
      if (allocated(err)) return
      call read_gmsh(path, mesh, err, n_unused)
      if (allocated(err)) return
      call check(err, n_unused == 2, 'two nodes (tags 7 and 9) are used by no triangle')
      call check(err, mesh%nv == 4 .and. mesh%nt == 2, '4 vertices and 2 triangles remain')
      if (allocated(err)) return
      call check(err, all(mesh%vertices(1, :) == [0.0_dp, 1.0_dp, 1.0_dp, 0.0_dp]) .and. &
                 all(mesh%vertices(2, :) == [0.0_dp, 0.0_dp, 1.0_dp, 1.0_dp]), 'used nodes in file order')
      call check(err, all(mesh%triangles(:, 1) == [1, 2, 3]) .and. all(mesh%triangles(:, 2) == [1, 3, 4]), &
                 'triangles renumbered past the dropped node')
      call check(err, mesh%n_boundary_vertices() == 4, 'every vertex on the boundary')
   end subroutine test_unused_nodes

   subroutine test_clockwise(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh

      call read_data('clockwise.msh', mesh, err)
      if (allocated(err)) return
      call check(err, mesh%n_flipped == 1, 'the clockwise triangle is flipped, the other kept')
      call check(err, all(mesh%triangles(:, 2) == [1, 3, 4]), 'now counter-clockwise')
      call check_close(err, mesh%total_area(), 1.0_dp, 4*epsilon(1.0_dp), 0.0_dp, 'area')
   end subroutine test_clockwise

   !> Every file in broken/ must give a bad-input error whose message names the file and, after
   !> it, says what is wrong (with the line where the reader knows it).
   subroutine test_broken(err)
      type(error_t), allocatable, intent(out) :: err

      integer, parameter :: n = 25
      character(len=*), parameter :: files(n) = [character(len=24) :: &
         'absent_node', 'bad_version', 'binary', 'count_mismatch', 'degenerate', &
         'duplicate_node', 'empty', 'extra_nodes', 'missing_nodes', 'nan_coordinate', &
         'no_triangles', 'non_numeric', 'nonmanifold', 'nonplanar', 'overflow_coordinate', &
         'quad', 'second_order', 'tetrahedron', 'truncated_nodes', 'unclosed_section', &
         'long_token', 'control_character', 'huge_node_count', &
         'huge_element_count', 'inf_coordinate']
      character(len=*), parameter :: expected(n) = [character(len=40) :: &
         ':14: triangle 2 refers to node tag 9', ':2: MSH version 4 is not supported', &
         ':2: binary', ':5: the header announces 5 nodes', 'zero area', &
         ':14: duplicate node tag 2', 'the file is empty', ':9: expected $EndNodes', &
         'no $Nodes section', &
         ':8: y coordinate "NaN" is not finite', 'no triangles', ':8: "abc" is not a number', &
         'more than two triangles', ':8: node tag 3 has z /= 0', ':8: z coordinate "1e999"', &
         ':13: element type 3 (4-node quadrangle)', ':22: element type 9', &
         ':18: element type 4 (3D', &
         ':9: the $Nodes section is truncated', ':4: section $PhysicalNames', &
         ':5: "3333333333', ':5: "3<0x7F>" is not an integer', &
         ':7: the $Nodes section is truncated', ':18: the $Elements section is truncated', &
         ':7: x coordinate "-Infinity" is not fini']
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path, name
      integer :: i, at
      character(len=95) :: printable

      do i = 1, 95
         printable(i:i) = achar(31 + i)
      end do
      do i = 1, n
         name = trim(files(i))//'.msh'
         call data_file('broken/'//name, path, err)
         if (allocated(err)) return
         call read_gmsh(path, mesh, got)
         call check(err, allocated(got), name//' is accepted')
         if (allocated(err)) return
         call check(err, got%code == exit_bad_input, name//': not a bad-input error')
         at = index(got%message, name)
         call check(err, at > 0, name//': message "'//got%message//'" does not name the file')
         if (allocated(err)) return
         call check(err, index(got%message(at + len(name):), trim(expected(i))) > 0, &
                    name//': message "'//got%message//'" lacks "'//trim(expected(i))//'"')
         call check(err, mesh%nv == 0 .and. mesh%nt == 0, name//': mesh left non-empty')
         ! found by the fuzzer: tokens were quoted whole and raw, control characters included
         call check(err, len(got%message) - at < 300, name//': message too long')
         call check(err, verify(got%message, printable) == 0, name//': control character in the message')
         if (allocated(err)) return
      end do
   end subroutine test_broken

   !> Coordinates at the reader's limit 1e150 are accepted: the mesh checks must not overflow
   !> on them. The overlap test multiplied two areas of 5e299 and trapped in debug builds.
   subroutine test_huge(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh

      call read_data('huge_coordinates.msh', mesh, err)
      if (allocated(err)) return
      call check(err, mesh%nv == 4 .and. mesh%nt == 2 .and. mesh%ne == 5, 'four nodes, two triangles')
      call check_close(err, mesh%total_area(), 1.0e300_dp, 8*epsilon(1.0_dp), 0.0_dp, 'area')
   end subroutine test_huge

   !> Coordinates in every form a writer may use (sign, no integer or fraction digits, E or D
   !> exponent in either case, exponent sign, -0) read as the values they denote, exactly.
   subroutine test_number_forms(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      real(dp), parameter :: expected(2, 5) = reshape([-1.0_dp, -1.0_dp, 1.0_dp, -1.0_dp, 1.0_dp, 1.0_dp, &
                                                      -1.0_dp, 1.0_dp, 0.25_dp, -0.125_dp], [2, 5])

      call read_data('number_forms.msh', mesh, err)
      if (allocated(err)) return
      call check(err, mesh%nv == 5 .and. mesh%nt == 4, 'five nodes, four triangles')
      if (allocated(err)) return
      call check(err, all(mesh%vertices == expected), 'every coordinate exact')
   end subroutine test_number_forms

   subroutine test_missing(err)
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: mesh
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path

      call data_file('does_not_exist.msh', path, err)
      if (allocated(err)) return
      call read_gmsh(path, mesh, got)
      call check(err, allocated(got), 'a missing file is an error')
      if (allocated(err)) return
      call check(err, got%code == exit_bad_input, 'a missing mesh file is bad input')
      call check(err, index(got%message, 'does_not_exist.msh') > 0, 'message names the file')
   end subroutine test_missing
   !> A file of more than 10^4 triangles in scattered order (a grid's nodes and triangles
   !> shuffled): asked for the file's numbers, the reader numbers the mesh along the domain, and
   !> every vertex and triangle maps back to the file's with its coordinates and corners; a
   !> defect in such a file is named by the file's triangle number, not the renumbered one.
   subroutine test_renumbered(err)
      type(error_t), allocatable, intent(out) :: err

      integer, parameter :: n = 75, nv = (n + 1)**2, nt = 2*n*n
      !> file triangle `broken` gets a repeated vertex in the second file
      integer, parameter :: broken = 5001
      real(dp) :: x(2, nv)
      integer(ip) :: tri(3, nt), node_of(nv), file_tri(nt)
      integer(ip), allocatable :: file_vertex(:), file_triangle(:)
      type(mesh_t) :: mesh
      type(error_t), allocatable :: got
      character(len=:), allocatable :: path
      integer :: i, j, k, t

      ! grid point k is node node_of(k) of the file; cell triangle t is element file_tri(t)
      do k = 1, nv
         node_of(k) = int(modulo(int(k - 1, 8)*4099_8, int(nv, 8)), ip) + 1
      end do
      do t = 1, nt
         file_tri(t) = int(modulo(int(t - 1, 8)*7919_8, int(nt, 8)), ip) + 1
      end do
      do j = 0, n
         do i = 0, n
            x(:, node_of(j*(n + 1) + i + 1)) = [real(i, dp)/n, real(j, dp)/n]
         end do
      end do
      t = 0
      do j = 0, n - 1
         do i = 0, n - 1
            k = j*(n + 1) + i + 1
            tri(:, file_tri(t + 1)) = node_of([k, k + 1, k + n + 2])
            tri(:, file_tri(t + 2)) = node_of([k, k + n + 2, k + n + 1])
            t = t + 2
         end do
      end do
      call write_msh22('large_grid.msh', x, tri, path)
      call read_gmsh(path, mesh, err, file_vertex=file_vertex, file_triangle=file_triangle)
      if (allocated(err)) return
      call check(err, size(file_vertex) == nv .and. size(file_triangle) == nt, 'file numbers of every vertex and triangle')
      if (allocated(err)) return
      call check(err, any(file_vertex /= [(k, k=1, nv)]) .and. any(file_triangle /= [(t, t=1, nt)]), &
                 'the mesh is renumbered')
      call check(err, all(mesh%vertices == x(:, file_vertex)), 'every vertex where the file has it')
      do t = 1, nt
         if (any(file_vertex(mesh%triangles(:, t)) /= cshift(tri(:, file_triangle(t)), corner_shift(t)))) then
            call check(err, .false., 'triangle '//int_text(t)//' has not the corners of its file triangle')
            return
         end if
      end do
      call check(err, mesh%n_flipped == 0 .and. mesh%n_boundary_vertices() == 4*n, 'orientation and boundary kept')
      if (allocated(err)) return
      ! without the file's numbers asked for, the file's order
      call read_gmsh(path, mesh, err)
      if (allocated(err)) return
      call check(err, all(mesh%vertices == x), 'file order without file numbers')
      if (allocated(err)) return

      tri(2, broken) = tri(1, broken)
      call write_msh22('large_grid_broken.msh', x, tri, path)
      call read_gmsh(path, mesh, got, file_vertex=file_vertex, file_triangle=file_triangle)
      call check(err, allocated(got), 'a repeated vertex is accepted')
      if (allocated(err)) return
      call check(err, index(got%message, 'triangle '//int_text(broken)//' repeats a vertex') > 0, &
                 'message "'//got%message//'" does not name file triangle '//int_text(broken))
   contains
      !> the rotation that takes triangle t's corners to its file triangle's (the same cycle)
      integer function corner_shift(t)
         integer, intent(in) :: t

         do corner_shift = 0, 2
            if (file_vertex(mesh%triangles(1, t)) == tri(1 + corner_shift, file_triangle(t))) return
         end do
         corner_shift = 0
      end function corner_shift
   end subroutine test_renumbered

   !> A MSH 2.2 file `name` in the test scratch directory, nodes tagged 1..n and triangles in
   !> the columns' order; path: where it is.
   subroutine write_msh22(name, x, tri, path)
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: x(:, :)
      integer(ip), intent(in) :: tri(:, :)
      character(len=:), allocatable, intent(out) :: path

      character(len=1024) :: dir
      integer :: unit, length, stat, k

      call get_environment_variable('TWOMEM_TEST_TMP', dir, length, stat)
      if (stat /= 0 .or. length == 0) error stop 'TWOMEM_TEST_TMP is not set (run through ctest)'
      path = trim(dir)//'/'//name
      open (newunit=unit, file=path, status='replace', action='write')
      write (unit, '(a)') '$MeshFormat', '2.2 0 8', '$EndMeshFormat', '$Nodes'
      write (unit, '(i0)') size(x, 2)
      do k = 1, size(x, 2)
         write (unit, '(i0,2(1x,es24.17),a)') k, x(:, k), ' 0'
      end do
      write (unit, '(a)') '$EndNodes', '$Elements'
      write (unit, '(i0)') size(tri, 2)
      do k = 1, size(tri, 2)
         write (unit, '(i0,a,3(1x,i0))') k, ' 2 0', tri(:, k)
      end do
      write (unit, '(a)') '$EndElements'
      close (unit)
   end subroutine write_msh22
end module test_gmsh
