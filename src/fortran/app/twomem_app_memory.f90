!> The memory a run needs, estimated before any refinement from the coarse mesh, and the refusal
!> of a run that cannot fit: a run of `mesh.levels = 7` would otherwise die minutes later in an
!> allocation. The finest mesh's size follows exactly from the coarse one (red refinement: every
!> edge gains a vertex, every triangle becomes four); the bytes per finest vertex were measured
!> (peak resident memory, /usr/bin/time -v, release build, one rank) for each method with the
!> estimators on and off, and are rounded up with a margin (docs/robustness.md, "Memory"). The
!> environment variable TWOMEM_MEMORY_CHECK=off skips the refusal (the estimate stays printed):
!> for a machine whose limits the check misjudges; an allocation that then fails still ends the
!> run with one line and exit 3 (src/c/twomem_guard.c).
module twomem_app_memory
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, exit_bad_input
   use twomem_base_system, only: memory_allowed_bytes
   use twomem_base_options, only: method_direct, method_adaptive
   use twomem_base_text, only: int_text
   use twomem_input_config, only: config_t
   use twomem_mesh_triangulation, only: mesh_t
   implicit none
   private

   public :: memory_estimate_t, estimate_memory, check_memory

   !> Bytes per finest-mesh vertex, measured (peak RSS, disk at 21k and 151k vertices; marginal
   !> cost between the two): GMRES 1540, estimators +1490, UMFPACK 4980; rounded up by about
   !> 30 %: the mesh hierarchy, the Newton system, the multigrid hierarchy or the UMFPACK factors,
   !> and the estimators' patch data.
   real(dp), parameter :: per_vertex_iterative = 2000.0_dp, per_vertex_estimators = 2000.0_dp
   !> UMFPACK's factors grow like n log n (nested-dissection fill in 2D): bytes per vertex and
   !> per doubling of the vertex count (4000 + 150 log2(151k) = 6580 against 4980 measured)
   real(dp), parameter :: per_vertex_direct = 4000.0_dp, per_vertex_direct_log = 150.0_dp
   !> what a run holds whatever its size (libraries, buffers, the coarse levels' work)
   real(dp), parameter :: base_bytes = 60.0e6_dp
   !> the Newton matrix has about this many entries per vertex; its CSR indices are 32-bit
   real(dp), parameter :: matrix_entries_per_vertex = 40.0_dp

   type :: memory_estimate_t
      !> vertices, triangles of the finest mesh (whole, all ranks)
      real(dp) :: vertices = 0, triangles = 0
      !> estimated peak bytes, all ranks together
      real(dp) :: bytes = 0
   end type memory_estimate_t

contains

   !> The estimate for `cfg` refined from the whole coarse mesh `coarse`.
   function estimate_memory(cfg, coarse) result(est)
      type(config_t), intent(in) :: cfg
      type(mesh_t), intent(in) :: coarse
      type(memory_estimate_t) :: est

      real(dp) :: nv, ne, nt, per_vertex
      integer :: l

      nv = real(coarse%nv, dp)
      ne = real(coarse%ne, dp)
      nt = real(coarse%nt, dp)
      do l = 1, cfg%mesh%levels
         nv = nv + ne
         ne = 2*ne + 3*nt
         nt = 4*nt
      end do
      est%vertices = nv
      est%triangles = nt
      select case (cfg%newton%linear)
      case (method_direct)
         per_vertex = per_vertex_direct + per_vertex_direct_log*log(max(nv, 2.0_dp))/log(2.0_dp)
      case default
         per_vertex = per_vertex_iterative
      end select
      if (cfg%newton%linear == method_adaptive .or. cfg%estimate%enabled) &
         per_vertex = per_vertex + per_vertex_estimators
      est%bytes = base_bytes + per_vertex*nv
   end function estimate_memory

   !> Refuse (exit 2, naming mesh.levels) a run whose estimate exceeds what this process may
   !> allocate, or whose matrix would overflow 32-bit indices. `ranks` share the work; the limit
   !> is this process's, so the comparison is with the per-rank share.
   subroutine check_memory(cfg, coarse, ranks, err)
      type(config_t), intent(in) :: cfg
      type(mesh_t), intent(in) :: coarse
      integer, intent(in) :: ranks
      type(error_t), allocatable, intent(out) :: err

      type(memory_estimate_t) :: est
      character(len=:), allocatable :: which
      character(len=16) :: setting
      integer(i8) :: allowed
      integer :: length, status
      real(dp) :: need

      est = estimate_memory(cfg, coarse)
      if (est%vertices*matrix_entries_per_vertex/ranks > real(huge(1_ip), dp)) then
         call make_error(err, exit_bad_input, 'mesh.levels', levels_text(cfg%mesh%levels)//' make about '// &
                         count_text(est%vertices)//' vertices; 32-bit indices allow about '// &
                         count_text(real(huge(1_ip), dp)/matrix_entries_per_vertex*ranks)//' (use fewer levels '// &
                         'or more MPI ranks)')
         return
      end if
      call get_environment_variable('TWOMEM_MEMORY_CHECK', setting, length, status)
      if (status == 0 .and. trim(setting) == 'off') return
      allowed = memory_allowed_bytes(which)
      if (allowed < 0) return
      need = est%bytes/ranks
      if (need > real(allowed, dp)) call make_error(err, exit_bad_input, 'mesh.levels', &
         levels_text(cfg%mesh%levels)//' need about '//gb_text(need)//' GB, this machine allows '// &
         gb_text(real(allowed, dp))//' GB ('//which//')')
   end subroutine check_memory

   pure function levels_text(levels) result(text)
      integer, intent(in) :: levels
      character(len=:), allocatable :: text

      text = int_text(levels)//merge(' level ', ' levels', levels == 1)
      text = trim(text)
   end function levels_text

   !> Gigabytes (10^9 bytes) with one decimal, two significant digits below 1.
   pure function gb_text(bytes) result(text)
      real(dp), intent(in) :: bytes
      character(len=:), allocatable :: text

      character(len=32) :: buffer
      real(dp) :: gb

      gb = bytes/1.0e9_dp
      if (gb >= 1.0_dp) then
         write (buffer, '(f0.1)') gb
      else
         write (buffer, '(f0.2)') gb
         if (buffer(1:1) == '.') buffer = '0'//buffer(1:len(buffer) - 1)
      end if
      text = trim(buffer)
   end function gb_text

   pure function count_text(x) result(text)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: text

      character(len=32) :: buffer

      write (buffer, '(es9.2)') x
      text = trim(adjustl(buffer))
   end function count_text
end module twomem_app_memory
