!> Reader for meshes written by Gmsh: MSH 2.2 and MSH 4.1, ASCII. It keeps the linear triangles
!> (element type 2), ignores points and lines (the boundary is recovered from the triangles),
!> physical groups and every section other than $MeshFormat, $Nodes and $Elements, and rejects
!> anything it cannot solve on (quadrangles, curved or 3D elements, binary files, other versions)
!> rather than guessing. Node tags are arbitrary positive integers, possibly sparse and in any
!> order. Nodes that no triangle uses (Gmsh writes them for geometry points such as a circle's
!> centre) are dropped and counted; the other nodes become vertices 1..nv in the order the file
!> lists them, or, where the caller asks for it, along the domain with each vertex's and
!> triangle's number in that order returned. Every defect is reported as bad input
!> naming the file and, where there is one, the line; geometric checks (orientation, zero areas,
!> non-manifold edges) are left to `mesh_t%init`, the gate every mesh passes.
module twomem_mesh_gmsh
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_bad_input, excerpt
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_spatial_order, only: renumber_along_curve, worth_reordering
   use twomem_mesh_gmsh_text, only: text_reader_t
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: read_gmsh

   integer, parameter :: msh22 = 22, msh41 = 41
   integer, parameter :: type_line = 1, type_triangle = 2, type_point = 15
   integer(i8), parameter :: max_count = huge(1_ip)
   integer(i8), parameter :: max_tag = 10_i8**18 - 1
   real(dp), parameter :: max_coordinate = 1.0e150_dp
   !> first size of the node and triangle arrays, which then double as entries are read
   integer(i8), parameter :: initial_capacity = 1024

   !> The file's content in its own numbering, before tags become vertex indices. Line numbers are
   !> kept so that problems found only once everything is read can still point into the file.
   type :: raw_mesh_t
      integer :: version = 0
      integer(ip) :: n_nodes = 0, n_triangles = 0
      !> counts the headers announce: the arrays grow towards them as entries are read
      integer(i8) :: max_nodes = 0, max_triangles = 0
      logical :: have_nodes = .false., have_elements = .false.
      integer(i8), allocatable :: node_tag(:)
      real(dp), allocatable :: xyz(:, :)
      integer, allocatable :: node_line(:)
      integer(i8), allocatable :: triangle_nodes(:, :), triangle_tag(:)
      integer, allocatable :: triangle_line(:)
   end type raw_mesh_t

contains

   !> Read the Gmsh file `path` into `mesh`. On error `mesh` is left empty. n_unused: how many
   !> nodes no triangle uses (dropped). With file_vertex and file_triangle, a mesh large enough
   !> to gain by it is numbered along the domain (twomem_mesh_spatial_order) before `mesh_t%init`
   !> builds its tables, which in a mesher's scattered order wait on memory (at 10^6 vertices
   !> 1.4–2.1 s, against half a second along the domain): file_vertex(a) and file_triangle(t)
   !> are then the numbers vertex a and triangle t have in the file's order, which messages and
   !> results keep; both are empty when the mesh keeps that order.
   subroutine read_gmsh(path, mesh, err, n_unused, file_vertex, file_triangle)
      character(len=*), intent(in) :: path
      type(mesh_t), intent(inout) :: mesh
      type(error_t), allocatable, intent(out) :: err
      integer(ip), intent(out), optional :: n_unused
      integer(ip), allocatable, intent(out), optional :: file_vertex(:), file_triangle(:)

      type(text_reader_t) :: reader
      type(raw_mesh_t) :: raw
      real(dp), allocatable :: vertices(:, :)
      integer(ip), allocatable :: triangles(:, :)
      integer(ip) :: dropped

      call mesh%free()
      if (present(n_unused)) n_unused = 0
      call reader%open(path, err)
      if (allocated(err)) return
      call read_sections(reader, raw, err)
      call reader%close()
      if (allocated(err)) return
      call number_vertices(raw, path, vertices, triangles, dropped, err)
      if (allocated(err)) return
      if (present(n_unused)) n_unused = dropped
      if (present(file_vertex) .and. present(file_triangle)) then
         ! (the coordinates are finite and below max_coordinate: the curve's keys need them so)
         if (worth_reordering(size(triangles, 2, kind=ip))) then
            call renumber_along_curve(vertices, triangles, file_vertex, file_triangle)
         else
            allocate (file_vertex(0), file_triangle(0))
         end if
      end if
      call mesh%init(vertices, triangles, path, err, vertex_names=file_vertex, triangle_names=file_triangle)
      if (allocated(err)) call mesh%free()
   end subroutine read_gmsh

   !> Sections may come in any order: tags are resolved only once everything is read.
   subroutine read_sections(reader, raw, err)
      type(text_reader_t), intent(inout) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      logical :: eof
      character(len=:), allocatable :: name

      call read_format(reader, raw%version, err)
      if (allocated(err)) return
      do
         call reader%next(eof, err)
         if (allocated(err) .or. eof) exit
         if (reader%n_tokens == 0) cycle
         name = reader%token(1)
         if (name(1:1) /= '$') then
            call reader%fail(err, 'expected a section such as $Nodes, found "'//reader%shown(1)//'"')
            return
         end if
         select case (name)
         case ('$Nodes')
            if (raw%have_nodes) then
               call reader%fail(err, 'a second $Nodes section')
            else if (raw%version == msh22) then
               call read_nodes_22(reader, raw, err)
            else
               call read_nodes_41(reader, raw, err)
            end if
            raw%have_nodes = .true.
         case ('$Elements')
            if (raw%have_elements) then
               call reader%fail(err, 'a second $Elements section')
            else if (raw%version == msh22) then
               call read_elements_22(reader, raw, err)
            else
               call read_elements_41(reader, raw, err)
            end if
            raw%have_elements = .true.
         case ('$MeshFormat')
            call reader%fail(err, 'a second $MeshFormat section')
         case default
            call skip_section(reader, name, err)
         end select
         if (allocated(err)) return
      end do
      if (allocated(err)) return
      if (.not. raw%have_nodes) then
         call make_error(err, exit_bad_input, reader%path, 'the file has no $Nodes section')
      else if (.not. raw%have_elements) then
         call make_error(err, exit_bad_input, reader%path, 'the file has no $Elements section')
      else if (raw%n_triangles == 0) then
         call make_error(err, exit_bad_input, reader%path, &
                         'the file holds no triangles (element type 2): nothing to solve on')
      end if
   end subroutine read_sections

   !> The header decides everything else: only ASCII MSH 2.2 and 4.1 are read. MSH 2.0 and 2.1
   !> share the 2.2 layout of $Nodes and $Elements and are read as 2.2; 4.0 differs from 4.1.
   subroutine read_format(reader, version, err)
      type(text_reader_t), intent(inout) :: reader
      integer, intent(out) :: version
      type(error_t), allocatable, intent(out) :: err

      logical :: eof
      real(dp) :: number
      integer(i8) :: file_type, data_size
      integer :: tenths

      version = 0
      do
         call reader%next(eof, err)
         if (allocated(err)) return
         if (eof) then
            call make_error(err, exit_bad_input, reader%path, 'the file is empty')
            return
         end if
         if (reader%n_tokens > 0) exit
      end do
      if (reader%token(1) /= '$MeshFormat') then
         call reader%fail(err, 'not a Gmsh mesh: the file must start with $MeshFormat, found "'// &
                          reader%shown(1)//'"')
         return
      end if
      call reader%next_data('$MeshFormat', 'the version line', err)
      if (allocated(err)) return
      call reader%get_real(1, 'MSH version', number, err)
      if (.not. allocated(err)) call reader%get_int(2, 0_i8, max_tag, 'file type', file_type, err)
      if (.not. allocated(err)) call reader%get_int(3, 0_i8, max_tag, 'data size', data_size, err)
      if (allocated(err)) return
      if (file_type /= 0) then
         call reader%fail(err, 'binary MSH files are not supported: write the mesh as ASCII '// &
                          '(Gmsh option Mesh.Binary = 0)')
         return
      end if
      ! nint of a huge number would trap, so only plausible versions are rounded
      tenths = 0
      if (abs(number) < 100.0_dp) then
         if (abs(10*number - nint(10*number)) < 1.0e-6_dp) tenths = nint(10*number)
      end if
      select case (tenths)
      case (20, 21, 22)
         version = msh22
      case (41)
         version = msh41
      end select
      if (version == 0) then
         call reader%fail(err, 'MSH version '//reader%shown(1)//' is not supported: write the '// &
                          'mesh as MSH 4.1 or 2.2 (Gmsh option Mesh.MshFileVersion)')
         return
      end if
      call reader%expect_tokens(3, 'version, file type, data size', err)
      if (allocated(err)) return
      call reader%expect_end('$MeshFormat', err)
   end subroutine read_format

   !> Sections the solver does not need ($PhysicalNames, $Entities, $NodeData, ...) are skipped
   !> whole; they must still be closed, or the file is truncated.
   subroutine skip_section(reader, name, err)
      type(text_reader_t), intent(inout) :: reader
      character(len=*), intent(in) :: name
      type(error_t), allocatable, intent(out) :: err

      logical :: eof
      integer :: start

      start = reader%line_no
      if (index(name, '$End') == 1) then
         call reader%fail(err, excerpt(name)//' closes a section that was never opened')
         return
      end if
      do
         call reader%next(eof, err)
         if (allocated(err)) return
         if (eof) then
            call make_error(err, exit_bad_input, reader%path//':'//int_text(start), &
                            'section '//excerpt(name)//' is never closed by '// &
                            excerpt('$End'//name(2:)))
            return
         end if
         if (reader%n_tokens == 0) cycle
         if (reader%token(1) == '$End'//name(2:)) return
      end do
   end subroutine skip_section

   !> MSH 2.2: a count, then one "tag x y z" line per node.
   subroutine read_nodes_22(reader, raw, err)
      type(text_reader_t), intent(inout) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      integer(i8) :: n
      integer(ip) :: k

      call reader%next_data('$Nodes', 'the number of nodes', err, 1, 'the number of nodes')
      if (allocated(err)) return
      call reader%get_int(1, 0_i8, max_count, 'number of nodes', n, err)
      if (allocated(err)) return
      raw%n_nodes = int(n, ip)
      raw%max_nodes = n
      do k = 1, raw%n_nodes
         call reader%next_data('$Nodes', 'node', err, 4, 'node tag, x, y, z', int(k, i8), n)
         if (allocated(err)) return
         call reserve_nodes(reader, raw, k, err)
         if (allocated(err)) return
         call reader%get_int(1, 1_i8, max_tag, 'node tag', raw%node_tag(k), err)
         if (allocated(err)) return
         call read_coordinates(reader, 2, raw, k, err)
         if (allocated(err)) return
      end do
      call reader%expect_end('$Nodes', err)
   end subroutine read_nodes_22

   !> MSH 4.1: a header, then blocks per geometric entity, each listing all its node tags first and
   !> then their coordinates (followed by parametric coordinates, which are not needed).
   subroutine read_nodes_41(reader, raw, err)
      type(text_reader_t), intent(inout) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      integer(i8) :: n_blocks, n, block, entity_dim, parametric, in_block, unused
      integer(ip) :: k, done
      integer :: header_line

      call reader%next_data('$Nodes', 'the header', err, &
                            4, 'numEntityBlocks numNodes minNodeTag maxNodeTag')
      if (allocated(err)) return
      call reader%get_int(1, 0_i8, max_count, 'number of entity blocks', n_blocks, err)
      if (.not. allocated(err)) call reader%get_int(2, 0_i8, max_count, 'number of nodes', n, err)
      ! the tag range is not needed: tags are looked up by sorting
      if (.not. allocated(err)) call reader%get_int(3, 0_i8, max_tag, 'smallest tag', unused, err)
      if (.not. allocated(err)) call reader%get_int(4, 0_i8, max_tag, 'largest tag', unused, err)
      if (allocated(err)) return
      header_line = reader%line_no
      raw%n_nodes = int(n, ip)
      raw%max_nodes = n
      done = 0
      do block = 1, n_blocks
         call reader%next_data('$Nodes', 'entity block', err, &
                               4, 'entityDim entityTag parametric numNodesInBlock', block, n_blocks)
         if (allocated(err)) return
         call reader%get_int(1, 0_i8, 3_i8, 'entity dimension', entity_dim, err)
         if (.not. allocated(err)) &
            call reader%get_int(3, 0_i8, 1_i8, 'parametric flag', parametric, err)
         if (.not. allocated(err)) &
            call reader%get_int(4, 0_i8, n - done, 'number of nodes in the block', in_block, err)
         if (allocated(err)) return
         do k = done + 1, done + int(in_block, ip)
            call reader%next_data('$Nodes', 'the tag of node', err, 1, 'a node tag', int(k, i8), n)
            if (allocated(err)) return
            call reserve_nodes(reader, raw, k, err)
            if (allocated(err)) return
            call reader%get_int(1, 1_i8, max_tag, 'node tag', raw%node_tag(k), err)
            if (allocated(err)) return
         end do
         do k = done + 1, done + int(in_block, ip)
            ! parametric coordinates follow x y z: one per dimension of the entity
            call reader%next_data('$Nodes', 'the coordinates of node', err, &
                                  3 + int(parametric*entity_dim), 'x y z (u v)', int(k, i8), n)
            if (allocated(err)) return
            call read_coordinates(reader, 1, raw, k, err)
            if (allocated(err)) return
         end do
         done = done + int(in_block, ip)
      end do
      if (done /= n) then
         call make_error(err, exit_bad_input, reader%path//':'//int_text(header_line), 'the header '// &
                         'announces '//int_text(n)//' nodes but the entity blocks hold '//int_text(done))
         return
      end if
      call reader%expect_end('$Nodes', err)
   end subroutine read_nodes_41

   !> x, y, z of node k from the tokens starting at `first`.
   subroutine read_coordinates(reader, first, raw, k, err)
      type(text_reader_t), intent(in) :: reader
      integer, intent(in) :: first
      type(raw_mesh_t), intent(inout) :: raw
      integer(ip), intent(in) :: k
      type(error_t), allocatable, intent(out) :: err

      character(len=*), parameter :: axis = 'xyz'
      integer :: i

      do i = 1, 3
         call reader%get_real(first + i - 1, axis(i:i)//' coordinate', raw%xyz(i, k), err)
         if (allocated(err)) return
         ! mesh_t squares coordinate differences; beyond this they would overflow
         if (abs(raw%xyz(i, k)) > max_coordinate) then
            call reader%fail(err, axis(i:i)//' coordinate '//reader%shown(first + i - 1)// &
                             ' is too large for a mesh (limit 1e150)')
            return
         end if
      end do
      raw%node_line(k) = reader%line_no
   end subroutine read_coordinates

   !> MSH 2.2: a count, then "tag type numTags tag... node..." per element.
   subroutine read_elements_22(reader, raw, err)
      type(text_reader_t), intent(inout) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      integer(i8) :: n, element_type, n_tags, tag
      integer(ip) :: k
      integer :: n_nodes

      call reader%next_data('$Elements', 'the number of elements', err, 1, 'the number of elements')
      if (allocated(err)) return
      call reader%get_int(1, 0_i8, max_count, 'number of elements', n, err)
      if (allocated(err)) return
      ! every element might be a triangle
      raw%max_triangles = n
      do k = 1, int(n, ip)
         call reader%next_data('$Elements', 'element', err, item=int(k, i8), total=n)
         if (allocated(err)) return
         call reader%get_int(1, 1_i8, max_tag, 'element tag', tag, err)
         if (.not. allocated(err)) &
            call reader%get_int(2, 1_i8, huge(1_i8), 'element type', element_type, err)
         if (.not. allocated(err)) &
            call reader%get_int(3, 0_i8, 1000_i8, 'number of element tags', n_tags, err)
         if (allocated(err)) return
         call element_nodes(reader, element_type, -1, n_nodes, err)
         if (allocated(err)) return
         call reader%expect_tokens(3 + int(n_tags) + n_nodes, 'tag, type, number of tags, '// &
                                   'tags, node tags', err)
         if (allocated(err)) return
         if (element_type == type_triangle) &
            call add_triangle(reader, 3 + int(n_tags), tag, raw, err)
         if (allocated(err)) return
      end do
      call reader%expect_end('$Elements', err)
   end subroutine read_elements_22

   !> MSH 4.1: a header, then blocks of one element type per geometric entity, one
   !> "tag node..." line per element.
   subroutine read_elements_41(reader, raw, err)
      type(text_reader_t), intent(inout) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      integer(i8) :: n_blocks, n, block, entity_dim, element_type, in_block, unused, tag, k, done
      integer :: n_nodes, header_line

      call reader%next_data('$Elements', 'the header', err, &
                            4, 'numEntityBlocks numElements minElementTag maxElementTag')
      if (allocated(err)) return
      call reader%get_int(1, 0_i8, max_count, 'number of entity blocks', n_blocks, err)
      if (.not. allocated(err)) &
         call reader%get_int(2, 0_i8, max_count, 'number of elements', n, err)
      if (.not. allocated(err)) call reader%get_int(3, 0_i8, max_tag, 'smallest tag', unused, err)
      if (.not. allocated(err)) call reader%get_int(4, 0_i8, max_tag, 'largest tag', unused, err)
      if (allocated(err)) return
      header_line = reader%line_no
      ! every element might be a triangle
      raw%max_triangles = n
      done = 0
      do block = 1, n_blocks
         call reader%next_data('$Elements', 'entity block', err, 4, &
                               'entityDim entityTag elementType numElementsInBlock', &
                               block, n_blocks)
         if (allocated(err)) return
         call reader%get_int(1, 0_i8, 3_i8, 'entity dimension', entity_dim, err)
         if (.not. allocated(err)) &
            call reader%get_int(3, 1_i8, huge(1_i8), 'element type', element_type, err)
         if (.not. allocated(err)) &
            call reader%get_int(4, 0_i8, n - done, 'number of elements in the block', in_block, err)
         if (allocated(err)) return
         call element_nodes(reader, element_type, int(entity_dim), n_nodes, err)
         if (allocated(err)) return
         do k = done + 1, done + in_block
            call reader%next_data('$Elements', 'element', err, 1 + n_nodes, &
                                  'element tag, node tags', k, n)
            if (allocated(err)) return
            call reader%get_int(1, 1_i8, max_tag, 'element tag', tag, err)
            if (allocated(err)) return
            if (element_type == type_triangle) call add_triangle(reader, 1, tag, raw, err)
            if (allocated(err)) return
         end do
         done = done + in_block
      end do
      if (done /= n) then
         call make_error(err, exit_bad_input, reader%path//':'//int_text(header_line), 'the header '// &
                         'announces '//int_text(n)//' elements but the entity blocks hold '//int_text(done))
         return
      end if
      call reader%expect_end('$Elements', err)
   end subroutine read_elements_41

   !> Room for node k. The arrays grow by doubling as nodes are read, up to the count the header
   !> announced, rather than being allocated for that count at once: a 100-byte file that
   !> announces two billion nodes must fail at its end, not reserve 77 GB first.
   subroutine reserve_nodes(reader, raw, k, err)
      type(text_reader_t), intent(in) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      integer(ip), intent(in) :: k
      type(error_t), allocatable, intent(out) :: err

      integer(i8), allocatable :: tag(:)
      real(dp), allocatable :: xyz(:, :)
      integer, allocatable :: line(:)
      integer(i8) :: old, new
      integer :: stat

      old = 0
      if (allocated(raw%node_tag)) old = size(raw%node_tag, kind=i8)
      if (k <= old) return
      new = min(raw%max_nodes, max(2*old, initial_capacity))
      allocate (tag(new), xyz(3, new), line(new), stat=stat)
      if (stat /= 0) then
         call reader%fail(err, 'cannot allocate memory for '//int_text(new)//' nodes')
         return
      end if
      if (old > 0) then
         tag(1:old) = raw%node_tag
         xyz(:, 1:old) = raw%xyz
         line(1:old) = raw%node_line
      end if
      call move_alloc(tag, raw%node_tag)
      call move_alloc(xyz, raw%xyz)
      call move_alloc(line, raw%node_line)
   end subroutine reserve_nodes

   !> Room for triangle t, grown like the nodes.
   subroutine reserve_triangles(reader, raw, t, err)
      type(text_reader_t), intent(in) :: reader
      type(raw_mesh_t), intent(inout) :: raw
      integer(ip), intent(in) :: t
      type(error_t), allocatable, intent(out) :: err

      integer(i8), allocatable :: nodes(:, :), tag(:)
      integer, allocatable :: line(:)
      integer(i8) :: old, new
      integer :: stat

      old = 0
      if (allocated(raw%triangle_tag)) old = size(raw%triangle_tag, kind=i8)
      if (t <= old) return
      new = min(raw%max_triangles, max(2*old, initial_capacity))
      allocate (nodes(3, new), tag(new), line(new), stat=stat)
      if (stat /= 0) then
         call reader%fail(err, 'cannot allocate memory for '//int_text(new)//' elements')
         return
      end if
      if (old > 0) then
         nodes(:, 1:old) = raw%triangle_nodes
         tag(1:old) = raw%triangle_tag
         line(1:old) = raw%triangle_line
      end if
      call move_alloc(nodes, raw%triangle_nodes)
      call move_alloc(tag, raw%triangle_tag)
      call move_alloc(line, raw%triangle_line)
   end subroutine reserve_triangles

   !> The node tags of a triangle, tokens after `offset`.
   subroutine add_triangle(reader, offset, tag, raw, err)
      type(text_reader_t), intent(in) :: reader
      integer, intent(in) :: offset
      integer(i8), intent(in) :: tag
      type(raw_mesh_t), intent(inout) :: raw
      type(error_t), allocatable, intent(out) :: err

      integer :: i
      integer(ip) :: t

      t = raw%n_triangles + 1
      call reserve_triangles(reader, raw, t, err)
      if (allocated(err)) return
      do i = 1, 3
         call reader%get_int(offset + i, 1_i8, max_tag, 'node tag', raw%triangle_nodes(i, t), err)
         if (allocated(err)) return
      end do
      raw%triangle_tag(t) = tag
      raw%triangle_line(t) = reader%line_no
      raw%n_triangles = t
   end subroutine add_triangle

   !> Number of nodes of an element type the reader accepts; any other type is an error that says
   !> why. `entity_dim` is the dimension of the entity the element lies on (MSH 4.1), -1 if unknown.
   subroutine element_nodes(reader, element_type, entity_dim, n_nodes, err)
      type(text_reader_t), intent(in) :: reader
      integer(i8), intent(in) :: element_type
      integer, intent(in) :: entity_dim
      integer, intent(out) :: n_nodes
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: name

      n_nodes = 0
      select case (element_type)
      case (type_point)
         n_nodes = 1
      case (type_line)
         n_nodes = 2
      case (type_triangle)
         n_nodes = 3
      end select
      if (n_nodes > 0) return
      select case (element_type)
      case (3)
         name = '4-node quadrangle'
      case (9)
         name = '6-node second-order triangle'
      case (10, 16)
         name = 'second-order quadrangle'
      case (20:25)
         name = 'higher-order triangle'
      case (8, 26:28)
         name = 'higher-order line'
      case (4)
         name = '3D element: 4-node tetrahedron'
      case (5)
         name = '3D element: 8-node hexahedron'
      case (6)
         name = '3D element: 6-node prism'
      case (7)
         name = '3D element: 5-node pyramid'
      case (11:14, 17:19, 29:31, 92, 93)
         name = '3D element: higher-order volume element'
      case default
         name = 'unknown to this reader'
      end select
      if (entity_dim == 3 .and. index(name, '3D') /= 1) name = '3D element: '//name
      call reader%fail(err, 'element type '//int_text(element_type)//' ('//name//') is not '// &
                       'supported: twomem reads planar meshes of linear triangles (type 2) only')
   end subroutine element_nodes

   !> Turn tags into indices: vertex k is the k-th node of the file that a triangle uses. Every
   !> node must be in the xy-plane and have a unique tag; every triangle node must exist. Nodes
   !> no triangle uses are dropped (`dropped` counts them).
   subroutine number_vertices(raw, path, vertices, triangles, dropped, err)
      type(raw_mesh_t), intent(in) :: raw
      character(len=*), intent(in) :: path
      real(dp), allocatable, intent(out) :: vertices(:, :)
      integer(ip), allocatable, intent(out) :: triangles(:, :)
      integer(ip), intent(out) :: dropped
      type(error_t), allocatable, intent(out) :: err

      integer(ip), allocatable :: order(:), new_index(:), at_tag(:)
      logical, allocatable :: used(:)
      integer(ip) :: k, t, i, lo, hi, mid, dup
      integer(i8) :: max_node_tag
      logical :: dense
      real(dp) :: scale

      ! CAD transformations can leave round-off in z; anything more is a 3D or tilted mesh.
      scale = max(1.0_dp, maxval(abs(raw%xyz(1:2, 1:raw%n_nodes))))
      do k = 1, raw%n_nodes
         if (abs(raw%xyz(3, k)) > 1.0e3_dp*epsilon(1.0_dp)*scale) then
            call make_error(err, exit_bad_input, path//':'//int_text(raw%node_line(k)), 'node tag '// &
                            int_text(raw%node_tag(k))//' has z /= 0: the mesh must lie in the xy-plane')
            return
         end if
      end do

      ! node k of each tag: a table where the tags are dense (Gmsh numbers nodes 1..n), else the
      ! tags sorted and searched by bisection, which at 10^6 nodes waited on memory for a second
      max_node_tag = 0
      if (raw%n_nodes > 0) max_node_tag = maxval(raw%node_tag(1:raw%n_nodes))
      dense = max_node_tag <= 2_i8*raw%n_nodes + 16
      ! report the repeat that comes first in the file
      dup = huge(dup)
      if (dense) then
         allocate (at_tag(max_node_tag))
         at_tag = 0
         do k = 1, raw%n_nodes
            if (at_tag(raw%node_tag(k)) /= 0) then
               dup = k
               exit
            end if
            at_tag(raw%node_tag(k)) = k
         end do
      else
         order = sort_order(raw%node_tag(1:raw%n_nodes))
         do k = 2, raw%n_nodes
            if (raw%node_tag(order(k)) == raw%node_tag(order(k - 1))) &
               dup = min(dup, max(order(k), order(k - 1)))
         end do
      end if
      if (dup < huge(dup)) then
         call make_error(err, exit_bad_input, path//':'//int_text(raw%node_line(dup)), &
                         'duplicate node tag '//int_text(raw%node_tag(dup)))
         return
      end if

      allocate (triangles(3, raw%n_triangles), used(raw%n_nodes))
      used = .false.
      do t = 1, raw%n_triangles
         do i = 1, 3
            k = 0
            if (dense) then
               if (raw%triangle_nodes(i, t) <= max_node_tag) k = at_tag(raw%triangle_nodes(i, t))
            else if (raw%n_nodes > 0) then
               ! binary search for the tag among the sorted node tags
               lo = 1
               hi = raw%n_nodes
               do while (lo < hi)
                  mid = lo + (hi - lo)/2
                  if (raw%node_tag(order(mid)) < raw%triangle_nodes(i, t)) then
                     lo = mid + 1
                  else
                     hi = mid
                  end if
               end do
               if (raw%node_tag(order(lo)) == raw%triangle_nodes(i, t)) k = order(lo)
            end if
            if (k == 0) then
               call make_error(err, exit_bad_input, path//':'//int_text(raw%triangle_line(t)), &
                               'triangle '//int_text(raw%triangle_tag(t))//' refers to node tag '// &
                               int_text(raw%triangle_nodes(i, t))//', which is not in $Nodes')
               return
            end if
            triangles(i, t) = k
            used(k) = .true.
         end do
      end do
      dropped = count(.not. used, kind=ip)
      if (dropped == 0) then
         vertices = raw%xyz(1:2, 1:raw%n_nodes)
         return
      end if
      allocate (new_index(raw%n_nodes), vertices(2, raw%n_nodes - dropped))
      new_index = 0
      i = 0
      do k = 1, raw%n_nodes
         if (.not. used(k)) cycle
         i = i + 1
         new_index(k) = i
         vertices(:, i) = raw%xyz(1:2, k)
      end do
      do t = 1, raw%n_triangles
         triangles(:, t) = new_index(triangles(:, t))
      end do
   end subroutine number_vertices

   !> Permutation that sorts `keys` ascending (stable bottom-up merge sort, O(n log n)).
   function sort_order(keys) result(order)
      integer(i8), intent(in) :: keys(:)
      integer(ip), allocatable :: order(:)

      integer(ip), allocatable :: work(:)
      integer(ip) :: n, width, left, mid, right, i, j, k

      n = int(size(keys), ip)
      allocate (order(n), work(n))
      order = [(i, i=1, n)]
      width = 1
      do while (width < n)
         left = 1
         do while (left <= n)
            mid = min(left + width, n + 1)
            right = min(left + 2*width, n + 1)
            i = left
            j = mid
            do k = left, right - 1
               ! min() keeps the indices valid: Fortran need not short-circuit .and./.or.
               if (i < mid .and. (j >= right .or. &
                                  keys(order(min(i, n))) <= keys(order(min(j, n))))) then
                  work(k) = order(i)
                  i = i + 1
               else
                  work(k) = order(j)
                  j = j + 1
               end if
            end do
            left = right
         end do
         order = work
         width = 2*width
      end do
   end function sort_order
end module twomem_mesh_gmsh
