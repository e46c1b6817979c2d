!> The problem data of a run from the configuration: the built-in cases and plain numbers as
!> before (`make_problem`), and otherwise the user's loads (`twomem_fem_user_data`), with
!> `problem.f1_file` / `f2_file` read here from HDF5. A file holds nodal values on the coarse or
!> on the finest mesh (told apart by their count) and, when it carries `/mesh/vertices` (as a
!> twomem result does), their coordinates, which must match the mesh's. Every rank reads the
!> file and keeps the values of its piece.
module twomem_app_loads
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_errors, only: error_t, make_error, prefix_error, exit_bad_input
   use twomem_base_comm, only: comm_t
   use twomem_input_config, only: config_t
   use twomem_mesh_hierarchy, only: mesh_hierarchy_t
   use twomem_fem_problem, only: problem_data_t
   use twomem_fem_cases, only: make_problem
   use twomem_fem_user_data, only: user_data_t, new_user_data
   use twomem_hdf5_file, only: h5_file_t
   use twomem_base_text, only: int_text
   implicit none
   private

   public :: make_data

contains

   !> The data of the case. Collective; every rank gets the same error.
   subroutine make_data(cfg, comm, hierarchy, data, err)
      type(config_t), intent(in) :: cfg
      type(comm_t), intent(in) :: comm
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      class(problem_data_t), allocatable, intent(out) :: data
      type(error_t), allocatable, intent(out) :: err

      type(user_data_t) :: user
      character(len=:), allocatable :: files(:)
      real(dp), allocatable :: values(:, :), column(:)
      integer :: alpha, level(2), finest, l
      logical :: use(2)

      associate (p => cfg%problem)
         if (len_trim(p%f1_formula//p%f2_formula//p%f1_file//p%f2_file) == 0) then
            ! numbers and built-in cases: the same objects, hence bit for bit the same runs
            call make_problem(p%exact, p%mu1, p%mu2, p%f1, p%f2, p%g, data, err)
            return
         end if
         call new_user_data(p%mu1, p%mu2, p%g, [p%f1, p%f2], [p%f1_formula, p%f2_formula], user, err)
         if (allocated(err)) return
         files = [character(len=len(p%f1_file)) :: p%f1_file, p%f2_file]
      end associate
      use = len_trim(files) > 0
      if (any(use)) then
         finest = hierarchy%levels
         level = 0
         do alpha = 1, 2
            if (.not. use(alpha)) cycle
            call read_nodal(trim(files(alpha)), 'problem.f'//achar(48 + alpha)//'_file', hierarchy, column, &
                            level(alpha), err)
            call comm%agree(err)
            if (allocated(err)) return
            ! both loads on one triangulation: a coarse one is interpolated to the finest when
            ! the other is given there (P1 on nested meshes: exact)
            l = level(alpha)
            if (any(use .and. level == finest) .or. (use(1) .and. use(2) .and. level(1) /= level(2))) then
               do while (l < finest)
                  call prolong_column(hierarchy, l, column)
                  l = l + 1
               end do
            end if
            if (.not. allocated(values)) allocate (values(size(column), 2), source=0.0_dp)
            values(:, alpha) = column
         end do
         l = merge(finest, 0, any(use .and. level == finest) .or. (use(1) .and. use(2) .and. level(1) /= level(2)))
         call user%set_nodal(hierarchy%meshes(l)%vertices, hierarchy%meshes(l)%triangles, values, use)
      end if
      allocate (data, source=user)
   end subroutine make_data

   subroutine prolong_column(hierarchy, l, column)
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      integer, intent(in) :: l
      real(dp), allocatable, intent(inout) :: column(:)

      real(dp), allocatable :: fine(:)

      allocate (fine(hierarchy%meshes(l + 1)%nv))
      call hierarchy%prolong(l + 1, column, fine)
      call move_alloc(fine, column)
   end subroutine prolong_column

   !> This rank's nodal values of 'FILE:DATASET' and the level they live on (0 or the finest).
   subroutine read_nodal(spec, key, hierarchy, column, level, err)
      character(len=*), intent(in) :: spec, key
      type(mesh_hierarchy_t), intent(in) :: hierarchy
      real(dp), allocatable, intent(out) :: column(:)
      integer, intent(out) :: level
      type(error_t), allocatable, intent(out) :: err

      type(h5_file_t) :: file
      type(error_t), allocatable :: ignored
      character(len=:), allocatable :: path, dataset
      real(dp), allocatable :: whole(:), xy(:, :)
      integer(i8), allocatable :: dims(:)
      integer(ip) :: n, a, g
      integer :: colon
      real(dp) :: scale, tol

      level = 0
      colon = index(spec, ':', back=.true.)
      path = spec(1:colon - 1)
      dataset = spec(colon + 1:)
      call file%open_read(path, err)
      if (allocated(err)) then
         err%code = exit_bad_input
         call prefix_error(err, key)
         return
      end if
      call read_checked(file, path, dataset, whole, dims, err)
      if (allocated(err)) then
         call file%close(ignored)
         call prefix_error(err, key)
         return
      end if
      n = size(whole, kind=ip)
      if (n == hierarchy%meshes(0)%nv_global) then
         level = 0
      else if (n == hierarchy%meshes(hierarchy%levels)%nv_global) then
         level = hierarchy%levels
      else
         call file%close(ignored)
         call make_error(err, exit_bad_input, key//': '//spec, int_text(int(n, i8))//' values, but the coarse mesh has '// &
                         int_text(int(hierarchy%meshes(0)%nv_global, i8))//' vertices and the finest '// &
                         int_text(int(hierarchy%meshes(hierarchy%levels)%nv_global, i8)))
         return
      end if
      associate (mesh => hierarchy%meshes(level))
         if (file%has('/mesh/vertices')) then
            call file%read_real('/mesh/vertices', xy, err)
            if (allocated(err)) then
               call file%close(ignored)
               call prefix_error(err, key)
               return
            end if
            if (size(xy, 1) /= 2 .or. size(xy, 2, kind=ip) /= n) then
               call file%close(ignored)
               call make_error(err, exit_bad_input, key//': '//path//':/mesh/vertices', 'expected ('// &
                               int_text(int(n, i8))//', 2) coordinates for the '//int_text(int(n, i8))//' values of '//dataset)
               return
            end if
            scale = max(1.0_dp, maxval(abs(mesh%vertices)))
            tol = 1.0e-8_dp*scale
            do a = 1, mesh%nv
               g = mesh%global_vertex_of(a)
               if (maxval(abs(xy(:, g) - mesh%vertices(:, a))) > tol) then
                  call file%close(ignored)
                  call make_error(err, exit_bad_input, key//': '//path//':/mesh/vertices', 'vertex '// &
                                  int_text(int(g - 1, i8))//' (0-based) lies at '//pair(xy(:, g))// &
                                  ' in the file but at '//pair(mesh%vertices(:, a))//' in the mesh')
                  return
               end if
            end do
         end if
         column = whole(mesh%global_vertex_of([(a, a=1, mesh%nv)]))
      end associate
      call file%close(err)
      if (allocated(err)) call prefix_error(err, key)
   end subroutine read_nodal

   !> A 1-D float dataset with finite values.
   subroutine read_checked(file, path, dataset, whole, dims, err)
      type(h5_file_t), intent(inout) :: file
      character(len=*), intent(in) :: path, dataset
      real(dp), allocatable, intent(out) :: whole(:)
      integer(i8), allocatable, intent(out) :: dims(:)
      type(error_t), allocatable, intent(out) :: err

      integer(ip) :: k

      if (.not. file%has(dataset)) then
         call make_error(err, exit_bad_input, path, 'no dataset '''//dataset//'''')
         return
      end if
      call file%get_dims(dataset, dims, err)
      if (allocated(err)) return
      if (size(dims) /= 1) then
         call make_error(err, exit_bad_input, path//':'//dataset, 'expected a 1-D dataset of nodal values, got '// &
                         int_text(int(size(dims), i8))//' dimensions')
         return
      end if
      call file%read_real(dataset, whole, err)
      if (allocated(err)) then
         err%code = exit_bad_input
         return
      end if
      do k = 1, size(whole, kind=ip)
         if (.not. ieee_is_finite(whole(k))) then
            call make_error(err, exit_bad_input, path//':'//dataset, 'value '//int_text(int(k - 1, i8))// &
                            ' (0-based) is not finite')
            return
         end if
      end do
   end subroutine read_checked

   function pair(x) result(s)
      real(dp), intent(in) :: x(2)
      character(len=:), allocatable :: s

      character(len=64) :: buf

      write (buf, '("(",g0.10,", ",g0.10,")")') x
      s = trim(buf)
   end function pair
end module twomem_app_loads
