!> Fuzz target: the Gmsh reader. Inputs are mutations of the valid meshes of tests/data/meshes
!> (both MSH versions, sparse tags, CRLF, clockwise triangles) and of a few broken ones, with a
!> dictionary of what the format's structure hangs on: section markers, version lines, counts
!> and tags at the edges of their ranges, non-finite and overflowing numbers, element types the
!> reader must refuse. `read_gmsh` must either accept, with a mesh fit for the solver, or reject
!> with a bad-input message that starts with the file name.
module fuzz_gmsh
   use twomem_base_errors, only: error_t
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_gmsh, only: read_gmsh
   use fuzz_random, only: rng_t
   use fuzz_mutate, only: word_t, mutate, add_word
   use fuzz_checks, only: message_problem, mesh_problem
   use fuzz_harness, only: fuzz_target_t, read_bytes
   implicit none
   private

   public :: gmsh_target_t

   type, extends(fuzz_target_t) :: gmsh_target_t
      type(word_t), allocatable :: seeds(:)
      type(word_t), allocatable :: words(:)
   contains
      procedure :: init
      procedure :: generate
      procedure :: try
   end type gmsh_target_t

   character(len=*), parameter :: seed_files(*) = [character(len=32) :: &
      'square_msh22.msh', 'square_msh41.msh', 'square_msh22_groups.msh', &
      'square_msh41_groups.msh', 'sparse_crlf.msh', 'clockwise.msh', 'lshape_msh41.msh', 'unused_nodes.msh', &
      'broken/count_mismatch.msh', 'broken/unclosed_section.msh', 'broken/second_order.msh', &
      'broken/nonmanifold.msh', 'broken/duplicate_node.msh']

contains

   !> Seeds from `data` (the tests/data directory).
   subroutine init(self, data)
      class(gmsh_target_t), intent(inout) :: self
      character(len=*), intent(in) :: data

      integer :: i
      character, parameter :: lf = achar(10)

      self%name = 'gmsh'
      self%extension = '.msh'
      allocate (self%seeds(size(seed_files)))
      do i = 1, size(seed_files)
         self%seeds(i)%s = read_bytes(data//'/meshes/'//trim(seed_files(i)))
      end do
      ! section markers, right and wrong
      call add_words(self%words, [character(len=24) :: '$MeshFormat', '$EndMeshFormat', &
         '$Nodes', '$EndNodes', '$Elements', '$EndElements', '$PhysicalNames', &
         '$EndPhysicalNames', '$Entities', '$EndEntities', '$NodeData', '$End', '$', '$$', &
         '$Comments', '$EndNodes$Elements'])
      ! versions and headers
      call add_words(self%words, [character(len=24) :: '2.2 0 8', '4.1 0 8', '4.1 1 8', &
         '4 0 8', '4.0 0 8', '2 0 8', '2.1 0 8', '3 0 8', '4.1 0', '4.1 0 8 9', '1e308 0 8', &
         '2.2', '41', '4.10000001'])
      ! numbers at the edges: counts, tags, element types, coordinates
      call add_words(self%words, [character(len=24) :: '0', '1', '-1', '2', '3', '4', '9', '15', &
         '-0', '+3', '2147483647', '2147483648', '-2147483649', '4294967297', &
         '999999999999999999', '9223372036854775807', '99999999999999999999', '1000000000', &
         '1e999', '-1e999', '1e308', '1.7976931348623157e308', '1e307', '1e151', '1e150', &
         '-1e150', '1e-320', '1e-400', '4.9e-324', 'nan', 'NaN', '-nan', 'inf', '-Infinity', &
         '0.5', '1.', '.5', '.', '-.', '1d3', '1D-3', '1e', '1e+', 'e5', '0x10', '1,2', '1/2', &
         '3*1', '1.5.2', '--1', '+-1', '1e-99999999999', '1e99999999999'])
      ! bytes a text reader may stumble over
      call add_word(self%words, achar(0))
      call add_word(self%words, achar(9))
      call add_word(self%words, achar(13))
      call add_word(self%words, achar(12))
      call add_word(self%words, achar(26))
      call add_word(self%words, char(195)//char(169))
      call add_word(self%words, char(255)//char(254))
      call add_word(self%words, '')
      ! whole lines: a node (both versions), an element of each kind, entity block headers
      call add_words(self%words, [character(len=40) :: '1 0 0 0', '1 0.5 0.5 0', '99 1 1 1', &
         '7 2 2 0 1 1 2 3', '7 2 0 1 1 2', '7 3 2 0 1 1 2 3 4', '7 9 2 0 1 1 2 3 4 5 6', &
         '7 15 2 0 1 1', '7 1 2 0 1 1 2', '7 4 2 0 1 1 2 3 4', '2 1 0 3', '2 1 1 3', '3 1 0 1', &
         '2 1 2 3', '2 1 3 1', '1 1 2 3', '1 2 3', '1 1 2', '0 0 0 0', '1 3 1 3', '2 1 0 0'])
      call add_word(self%words, '$Nodes'//lf//'1'//lf//'1 0 0 0'//lf//'$EndNodes')
      call add_word(self%words, '$Elements'//lf//'0'//lf//'$EndElements')
      call add_word(self%words, '$PhysicalNames'//lf//'1'//lf//'2 1 "domain"'//lf//'$EndPhysicalNames')
   end subroutine init

   subroutine add_words(words, list)
      type(word_t), allocatable, intent(inout) :: words(:)
      character(len=*), intent(in) :: list(:)

      integer :: i

      do i = 1, size(list)
         call add_word(words, trim(list(i)))
      end do
   end subroutine add_words

   subroutine generate(self, rng, text)
      class(gmsh_target_t), intent(in) :: self
      type(rng_t), intent(inout) :: rng
      character(len=:), allocatable, intent(out) :: text

      integer :: i

      ! the index first: gfortran may evaluate a subscript twice (for the length and for the
      ! text), and each evaluation here draws a new number
      i = rng%between(1, size(self%seeds))
      text = self%seeds(i)%s
      call mutate(text, rng, self%words)
   end subroutine generate

   subroutine try(self, path, text, accepted, problem, message)
      class(gmsh_target_t), intent(in) :: self
      character(len=*), intent(in) :: path, text
      logical, intent(out) :: accepted
      character(len=:), allocatable, intent(out) :: problem, message

      type(mesh_t) :: mesh
      type(error_t), allocatable :: err

      call read_gmsh(path, mesh, err)
      accepted = .not. allocated(err)
      if (accepted) then
         problem = mesh_problem(mesh)
      else
         problem = message_problem(err, path)
         if (allocated(err%message)) message = err%message
         ! a rejected file must leave no half-built mesh behind
         if (len(problem) == 0 .and. (mesh%nv /= 0 .or. mesh%nt /= 0)) &
            problem = 'a rejected file left a mesh behind'
      end if
   end subroutine try
end module fuzz_gmsh
