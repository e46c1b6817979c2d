!> The XDMF 3 sidecar that lets ParaView (or VisIt) open a twomem result file: a small XML file
!> beside the HDF5 file that describes the triangle mesh and points at the nodal and per-element
!> datasets inside it, so the heavy data is never duplicated. The file is written under a
!> temporary name in the same directory and renamed, so a reader never sees half of it.
module twomem_io_xdmf
   use twomem_base_kinds, only: ip
   use twomem_base_errors, only: error_t, make_error, exit_io
   use twomem_base_system, only: rename_file, remove_file, process_id, base_name, register_temporary, &
      unregister_temporary
   implicit none
   private

   public :: write_xdmf, write_xdmf_steps

contains

   !> Describe the result file `h5_name` (relative to the directory of `xdmf_path`) with `nv`
   !> vertices and `nt` triangles; `node_fields` and `cell_fields` are full dataset paths
   !> ('/solution/u1', '/estimators/eta_total'), shown under their last path component.
   subroutine write_xdmf(xdmf_path, h5_name, nv, nt, node_fields, cell_fields, err)
      character(len=*), intent(in) :: xdmf_path, h5_name
      integer(ip), intent(in) :: nv, nt
      character(len=*), intent(in) :: node_fields(:), cell_fields(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: tmp_path
      character(len=256) :: msg
      integer :: unit, ios

      call open_temporary(xdmf_path, tmp_path, unit, err)
      if (allocated(err)) return
      ios = 0
      msg = ''
      call emit(unit, '<?xml version="1.0" encoding="UTF-8"?>', ios, msg)
      call emit(unit, '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">', ios, msg)
      call emit(unit, '  <Domain>', ios, msg)
      call emit_grid(unit, xml_escape(trim(h5_name)), 'twomem', '/mesh', '', nv, nt, node_fields, cell_fields, &
                     ios, msg)
      call emit(unit, '  </Domain>', ios, msg)
      call emit(unit, '</Xdmf>', ios, msg)
      call finish_temporary(xdmf_path, tmp_path, unit, ios, msg, err)
   end subroutine write_xdmf

   !> A temporal collection over the groups `groups` of the result file `h5_name` (each holding
   !> `vertices`, `triangles` and the named node and cell fields): ParaView's time steps walk
   !> through an adaptive run's meshes, step k at time k.
   subroutine write_xdmf_steps(xdmf_path, h5_name, groups, nv, nt, node_fields, cell_fields, err)
      character(len=*), intent(in) :: xdmf_path, h5_name
      character(len=*), intent(in) :: groups(:)
      integer(ip), intent(in) :: nv(:), nt(:)
      character(len=*), intent(in) :: node_fields(:), cell_fields(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=:), allocatable :: tmp_path, h5
      character(len=256) :: msg
      integer :: unit, ios, k

      call open_temporary(xdmf_path, tmp_path, unit, err)
      if (allocated(err)) return
      h5 = xml_escape(trim(h5_name))
      ios = 0
      msg = ''
      call emit(unit, '<?xml version="1.0" encoding="UTF-8"?>', ios, msg)
      call emit(unit, '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">', ios, msg)
      call emit(unit, '  <Domain>', ios, msg)
      call emit(unit, '    <Grid Name="adapt" GridType="Collection" CollectionType="Temporal">', ios, msg)
      do k = 1, size(groups)
         call emit_grid(unit, h5, 'step '//int_text(k), trim(groups(k)), trim(groups(k))//'/', nv(k), nt(k), &
                        node_fields, cell_fields, ios, msg, time=k)
      end do
      call emit(unit, '    </Grid>', ios, msg)
      call emit(unit, '  </Domain>', ios, msg)
      call emit(unit, '</Xdmf>', ios, msg)
      call finish_temporary(xdmf_path, tmp_path, unit, ios, msg, err)
   end subroutine write_xdmf_steps

   !> One triangle grid: the mesh datasets `mesh_group`/triangles and /vertices, the fields at
   !> `field_prefix`//name, and with `time` the time value of a temporal collection's member.
   subroutine emit_grid(unit, h5, name, mesh_group, field_prefix, nv, nt, node_fields, cell_fields, ios, msg, time)
      integer, intent(in) :: unit
      character(len=*), intent(in) :: h5, name, mesh_group, field_prefix
      integer(ip), intent(in) :: nv, nt
      character(len=*), intent(in) :: node_fields(:), cell_fields(:)
      integer, intent(inout) :: ios
      character(len=*), intent(inout) :: msg
      integer, intent(in), optional :: time

      character(len=:), allocatable :: nv_text, nt_text
      integer :: i

      nv_text = int_text(int(nv))
      nt_text = int_text(int(nt))
      call emit(unit, '    <Grid Name="'//name//'" GridType="Uniform">', ios, msg)
      if (present(time)) call emit(unit, '      <Time Value="'//int_text(time)//'"/>', ios, msg)
      call emit(unit, '      <Topology TopologyType="Triangle" NumberOfElements="'//nt_text//'">', ios, msg)
      call emit_item(unit, h5, mesh_group//'/triangles', nt_text//' 3', 'Int', '4', ios, msg)
      call emit(unit, '      </Topology>', ios, msg)
      call emit(unit, '      <Geometry GeometryType="XY">', ios, msg)
      call emit_item(unit, h5, mesh_group//'/vertices', nv_text//' 2', 'Float', '8', ios, msg)
      call emit(unit, '      </Geometry>', ios, msg)
      do i = 1, size(node_fields)
         call emit_attribute(unit, h5, field_prefix//trim(node_fields(i)), 'Node', nv_text, ios, msg)
      end do
      do i = 1, size(cell_fields)
         call emit_attribute(unit, h5, field_prefix//trim(cell_fields(i)), 'Cell', nt_text, ios, msg)
      end do
      call emit(unit, '    </Grid>', ios, msg)
   end subroutine emit_grid

   !> Open a temporary file beside `xdmf_path`, registered for removal should the run be killed.
   subroutine open_temporary(xdmf_path, tmp_path, unit, err)
      character(len=*), intent(in) :: xdmf_path
      character(len=:), allocatable, intent(out) :: tmp_path
      integer, intent(out) :: unit
      type(error_t), allocatable, intent(out) :: err

      character(len=256) :: msg
      integer :: ios

      tmp_path = trim(xdmf_path)//'.tmp'//int_text(process_id())
      call register_temporary(tmp_path)
      open (newunit=unit, file=tmp_path, status='replace', action='write', form='formatted', &
            iostat=ios, iomsg=msg)
      if (ios /= 0) then
         call unregister_temporary()
         call make_error(err, exit_io, xdmf_path, 'cannot write XDMF file: '//trim(msg))
      end if
   end subroutine open_temporary

   !> Close the temporary file and rename it to `xdmf_path`, or delete it when a write failed
   !> (`ios`, `msg`: the first failure), so that a reader never sees half of the file.
   subroutine finish_temporary(xdmf_path, tmp_path, unit, ios, msg, err)
      character(len=*), intent(in) :: xdmf_path, tmp_path
      integer, intent(in) :: unit
      integer, intent(inout) :: ios
      character(len=*), intent(inout) :: msg
      type(error_t), allocatable, intent(out) :: err

      integer :: ignored

      if (ios == 0) then
         close (unit, iostat=ios, iomsg=msg)
      else
         close (unit, status='delete', iostat=ignored)
      end if
      if (ios /= 0) then
         call remove_file(tmp_path)
         call unregister_temporary()
         call make_error(err, exit_io, xdmf_path, 'cannot write XDMF file: '//trim(msg))
         return
      end if
      call rename_file(tmp_path, xdmf_path, err)
      if (allocated(err)) call remove_file(tmp_path)
      call unregister_temporary()
   end subroutine finish_temporary

   !> A scalar field, named after the dataset's last path component.
   subroutine emit_attribute(unit, h5, dset_path, center, dims, ios, msg)
      integer, intent(in) :: unit
      character(len=*), intent(in) :: h5, dset_path, center, dims
      integer, intent(inout) :: ios
      character(len=*), intent(inout) :: msg

      call emit(unit, '      <Attribute Name="'//xml_escape(base_name(dset_path))// &
                '" AttributeType="Scalar" Center="'//center//'">', ios, msg)
      call emit_item(unit, h5, dset_path, dims, 'Float', '8', ios, msg)
      call emit(unit, '      </Attribute>', ios, msg)
   end subroutine emit_attribute

   subroutine emit_item(unit, h5, dset_path, dims, data_type, precision, ios, msg)
      integer, intent(in) :: unit
      character(len=*), intent(in) :: h5, dset_path, dims, data_type, precision
      integer, intent(inout) :: ios
      character(len=*), intent(inout) :: msg

      call emit(unit, '        <DataItem DataType="'//data_type//'" Precision="'//precision// &
                '" Dimensions="'//dims//'" Format="HDF">'//h5//':'//xml_escape(dset_path)// &
                '</DataItem>', ios, msg)
   end subroutine emit_item

   !> Write one line unless an earlier write failed: the first failure is the one reported.
   subroutine emit(unit, line, ios, msg)
      integer, intent(in) :: unit
      character(len=*), intent(in) :: line
      integer, intent(inout) :: ios
      character(len=*), intent(inout) :: msg

      if (ios /= 0) return
      write (unit, '(a)', iostat=ios, iomsg=msg) line
   end subroutine emit

   pure function int_text(i) result(text)
      integer, intent(in) :: i
      character(len=:), allocatable :: text

      character(len=24) :: buffer

      write (buffer, '(i0)') i
      text = trim(buffer)
   end function int_text

   !> File and dataset names may contain characters that are markup in XML.
   pure function xml_escape(text) result(escaped)
      character(len=*), intent(in) :: text
      character(len=:), allocatable :: escaped

      integer :: i

      escaped = ''
      do i = 1, len(text)
         select case (text(i:i))
         case ('&')
            escaped = escaped//'&amp;'
         case ('<')
            escaped = escaped//'&lt;'
         case ('>')
            escaped = escaped//'&gt;'
         case ('"')
            escaped = escaped//'&quot;'
         case default
            escaped = escaped//text(i:i)
         end select
      end do
   end function xml_escape
end module twomem_io_xdmf
