!> The only Fortran that knows the METIS glue (src/c/twomem_metis.c): a partition of a mesh's
!> triangles into `parts` parts through the dual graph, for the distributed runs.
module twomem_mesh_metis
   use, intrinsic :: iso_c_binding, only: c_int
   use twomem_base_kinds, only: ip
   use twomem_base_errors, only: error_t, make_error, exit_io, exit_bad_input
   implicit none
   private

   public :: metis_partition

   interface
      integer(c_int) function twomem_metis_partition(nt, nv, triangles, nparts, part) bind(C)
         import :: c_int
         integer(c_int), value :: nt, nv, nparts
         integer(c_int), intent(in) :: triangles(*)
         integer(c_int), intent(out) :: part(*)
      end function twomem_metis_partition
   end interface

   !> METIS's status codes (metis.h)
   integer(c_int), parameter :: metis_ok = 1, metis_error_input = -2, metis_error_memory = -3

contains

   !> part(t) ∈ 0..parts−1 for every triangle of the mesh (nv vertices, triangles (3, nt)).
   subroutine metis_partition(nv, triangles, parts, part, err)
      integer(ip), intent(in) :: nv
      integer(ip), intent(in) :: triangles(:, :)
      integer, intent(in) :: parts
      integer(ip), intent(out) :: part(:)
      type(error_t), allocatable, intent(out) :: err

      integer(c_int) :: status

      if (parts > size(triangles, 2)) then
         call make_error(err, exit_bad_input, 'partition', 'more MPI ranks than coarse triangles: use fewer ranks '// &
                         'or a finer coarse mesh (mesh.coarse_h)')
         return
      end if
      status = twomem_metis_partition(int(size(triangles, 2), c_int), int(nv, c_int), triangles, int(parts, c_int), part)
      select case (status)
      case (metis_ok)
      case (metis_error_memory)
         call make_error(err, exit_io, 'METIS', 'out of memory while partitioning the coarse mesh')
      case (metis_error_input)
         call make_error(err, exit_io, 'METIS', 'the coarse mesh was rejected (METIS_ERROR_INPUT)')
      case default
         call make_error(err, exit_io, 'METIS', 'partitioning the coarse mesh failed')
      end select
   end subroutine metis_partition
end module twomem_mesh_metis
