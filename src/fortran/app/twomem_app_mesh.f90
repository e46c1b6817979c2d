!> The mesh hierarchy of a run: rank 0 makes the coarse mesh (a built-in generator or a Gmsh
!> file) and shares it, every rank takes its piece of the partition (`twomem_mesh_partition`)
!> and refines it `mesh.levels` times. One rank takes the whole mesh: the same path, nothing
!> cut. The sizes printed are those of the whole meshes. Before anything is refined, rank 0
!> refuses a hierarchy that would not fit in memory (twomem_app_memory).
module twomem_app_mesh
   use, intrinsic :: iso_fortran_env, only: output_unit
   use twomem_base_kinds, only: dp, ip
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_comm, only: comm_t
   use twomem_base_options, only: domain_disk, domain_square, domain_gmsh, exact_none
   use twomem_input_config, only: config_t
   use twomem_input_keys, only: k_exact
   use twomem_input_options, only: word_of_kind
   use twomem_mesh_triangulation, only: mesh_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_mesh_generators, only: make_disk, make_square, disk_boundary_spacing
   use twomem_mesh_gmsh, only: read_gmsh
   use twomem_mesh_partition, only: share_mesh, distribute_coarse, number_as_file
   use twomem_app_memory, only: check_memory
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: build_hierarchy

contains

   !> This rank's piece of the refinement hierarchy of the case's mesh. Collective.
   subroutine build_hierarchy(cfg, comm, hierarchy, err)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(inout) :: hierarchy
      type(error_t), allocatable, intent(out) :: err

      type(mesh_t) :: whole, piece
      integer(ip), allocatable :: file_vertex(:), file_triangle(:)
      integer :: l

      if (comm%is_root()) call coarse_mesh(cfg, whole, file_vertex, file_triangle, err)
      if (comm%is_root() .and. .not. allocated(err)) call check_memory(cfg, whole, comm%size, err)
      call comm%agree(err)
      if (allocated(err)) return
      call share_mesh(comm, whole, 'coarse mesh', err)
      call comm%agree(err)
      if (allocated(err)) return
      call comm%bcast(file_vertex)
      call comm%bcast(file_triangle)
      call distribute_coarse(comm, whole, piece, err)
      call comm%agree(err)
      if (allocated(err)) return
      call whole%free()
      ! the reader numbered a large file's mesh along the domain: the result keeps the file's numbering
      if (size(file_vertex) > 0) call number_as_file(piece, file_vertex, file_triangle)
      call hierarchy%init(piece, cfg%mesh%levels, err)
      call comm%agree(err)
      if (allocated(err)) return
      ! every level is refined by now: its edge tables go (16 MB of the coarser levels at 10⁶
      ! vertices, beside the finest mesh's 61)
      do l = 0, hierarchy%levels
         associate (m => hierarchy%meshes(l))
            call m%drop_refinement_tables()
            call report_level(comm, l, m)
         end associate
      end do
   end subroutine build_hierarchy

   !> The whole coarse mesh (rank 0 only); for a Gmsh file numbered along the domain, the file's
   !> numbers of its vertices and triangles (read_gmsh; empty otherwise).
   subroutine coarse_mesh(cfg, coarse, file_vertex, file_triangle, err)
      type(config_t), intent(in) :: cfg
      type(mesh_t), intent(inout) :: coarse
      integer(ip), allocatable, intent(out) :: file_vertex(:), file_triangle(:)
      type(error_t), allocatable, intent(out) :: err

      real(dp) :: boundary_h
      integer(ip) :: n_unused

      allocate (file_vertex(0), file_triangle(0))
      select case (cfg%mesh%domain)
      case (domain_disk)
         boundary_h = cfg%mesh%boundary_h
         if (boundary_h <= 0.0_dp) boundary_h = disk_boundary_spacing(cfg%mesh%coarse_h, cfg%mesh%levels)
         write (output_unit, '("mesh: unit disk, coarse_h ",g0.4,", boundary spacing ",g0.4,", ",i0," levels")') &
            cfg%mesh%coarse_h, boundary_h, cfg%mesh%levels
         call make_disk(cfg%mesh%coarse_h, boundary_h, coarse, err)
      case (domain_square)
         write (output_unit, '("mesh: square (-1,1)^2, coarse_h ",g0.4,", ",i0," levels")') &
            cfg%mesh%coarse_h, cfg%mesh%levels
         call make_square(cfg%mesh%coarse_h, coarse, err)
      case (domain_gmsh)
         write (output_unit, '("mesh: ",a,", ",i0," levels")') trim(cfg%mesh%file), cfg%mesh%levels
         call read_gmsh(trim(cfg%mesh%file), coarse, err, n_unused, file_vertex, file_triangle)
         if (allocated(err)) return
         if (n_unused > 0) write (output_unit, '("  note: ",i0," nodes used by no triangle dropped")') n_unused
         if (coarse%n_flipped > 0) write (output_unit, &
            '("  note: ",i0," clockwise triangles reoriented")') coarse%n_flipped
         if (cfg%problem%exact /= exact_none) call check_unit_disk(coarse, file_vertex, trim(cfg%mesh%file), &
                                                                  word_of_kind(k_exact, cfg%problem%exact), err)
      end select
   end subroutine coarse_mesh

   !> The exact solutions live on the unit disk: a Gmsh mesh for them must have its boundary
   !> vertices on the unit circle (to 1e-6, ample for any mesh generator's output) and lie
   !> inside it. Red refinement keeps boundary vertices on the coarse chords, so the check of
   !> the coarse mesh is the one that matters.
   subroutine check_unit_disk(mesh, file_vertex, path, exact, err)
      type(mesh_t), intent(in) :: mesh
      !> the file's numbers of the vertices (empty: their own)
      integer(ip), intent(in) :: file_vertex(:)
      character(len=*), intent(in) :: path, exact
      type(error_t), allocatable, intent(out) :: err

      real(dp), parameter :: tol = 1.0e-6_dp
      real(dp) :: r
      character(len=80) :: text
      integer(ip) :: a, named

      do a = 1, mesh%nv
         r = norm2(mesh%vertices(:, a))
         if ((mesh%boundary_vertex(a) .and. abs(r - 1) > tol) .or. r > 1 + tol) then
            write (text, '("(",g0.8,", ",g0.8,"), |x| = ",g0.10)') mesh%vertices(:, a), r
            named = a
            if (size(file_vertex) > 0) named = file_vertex(a)
            call make_error(err, exit_bad_input, path, "problem.exact='"//exact//"' needs a mesh of the unit disk: "// &
                            merge('boundary', 'interior', mesh%boundary_vertex(a))//' vertex '//int_text(named)// &
                            ' at '//trim(text)//' is not on the unit circle (tolerance 1e-6)')
            return
         end if
      end do
   end subroutine check_unit_disk

   !> One line per level: whole-mesh sizes and the range of element sizes. Collective.
   subroutine report_level(comm, l, m)
      type(comm_t), intent(in) :: comm
      integer, intent(in) :: l
      type(mesh_t), intent(in) :: m

      real(dp) :: h_min, h_max, h
      integer(ip) :: t

      ! (no rank without triangles reaches here; its extremes would be ±huge)
      h_min = huge(1.0_dp)
      h_max = -huge(1.0_dp)
      !$omp parallel do default(none) shared(m) private(t, h) reduction(min:h_min) reduction(max:h_max) &
      !$omp schedule(static)
      do t = 1, m%nt_owned
         h = m%diameter_of(t)
         h_min = min(h_min, h)
         h_max = max(h_max, h)
      end do
      !$omp end parallel do
      h_min = comm%min_real(h_min)
      h_max = comm%max(h_max)
      if (comm%is_root()) write (output_unit, '("  level ",i2,": ",i9," vertices ",i10," triangles  h ",es9.3, &
           &" .. ",es9.3)') l, m%nv_global, m%nt_global, h_min, h_max
   end subroutine report_level
end module twomem_app_mesh
