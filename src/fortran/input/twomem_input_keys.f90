!> The keys of the case file: one table of `key_t` rows (group, name, type of value), in the
!> order of the documentation and of the echoed input, and the lookups by name. Loading,
!> validation and the echo all go by this table. A key is a named row number (`k_*`) and its
!> row; the rest is where it is used (its component in `config_t`, its store and echo lines,
!> its rule). The names have a fixed width, checked at compile time.
module twomem_input_keys
   implicit none
   private

   public :: key_t, keys, n_keys, n_groups, group_names
   public :: type_word, type_path, type_real, type_int, type_logical, type_load
   public :: k_domain, k_mesh_file, k_coarse_h, k_levels, k_boundary_h, &
             k_mu1, k_mu2, k_f1, k_f2, k_g, k_exact, k_f1_file, k_f2_file, &
             k_cfun, k_linear, k_newton_max_it, k_tol, k_gamma_lin, k_initial, k_line_search, k_fb_finish, &
             k_restart, k_gmres_max_it, k_rtol, k_precond, k_forcing, &
             k_gamma_alg, k_enabled, k_every, k_flux, k_alg_levels, k_criteria, k_checks, k_bound, &
             k_output_file, k_fields, k_estimators, k_history, k_xdmf, &
             k_adapt_tol, k_theta, k_max_steps, k_max_vertices
   public :: find_group, find_key, group_list, key_list, key_name, group_name

   !> width of group and key names
   integer, parameter :: name_len = 16

   integer, parameter :: group_mesh = 1, group_problem = 2, group_newton = 3, group_gmres = 4, &
                         group_estimate = 5, group_output = 6, group_adapt = 7
   character(len=name_len), parameter :: group_names(*) = [character(len=name_len) :: &
      'mesh', 'problem', 'newton', 'gmres', 'estimate', 'output', 'adapt']
   integer, parameter :: n_groups = size(group_names)

   !> the type of a key's value. type_load: a real number, or a formula (quoted in a file; a bare
   !> override that is not a number is a formula too)
   integer, parameter :: type_word = 1, type_path = 2, type_real = 3, type_int = 4, type_logical = 5, &
                         type_load = 6

   type :: key_t
      !> its row in `keys` (k_*), repeated so that a row shows which name it is
      integer :: id
      integer :: group
      character(len=name_len) :: name
      integer :: type
   end type key_t

   integer, parameter :: k_domain = 1, k_mesh_file = 2, k_coarse_h = 3, k_levels = 4, k_boundary_h = 5, &
      k_mu1 = 6, k_mu2 = 7, k_f1 = 8, k_f2 = 9, k_g = 10, k_exact = 11, k_f1_file = 12, k_f2_file = 13, &
      k_cfun = 14, k_linear = 15, k_newton_max_it = 16, k_tol = 17, k_gamma_lin = 18, k_initial = 19, &
      k_line_search = 20, k_fb_finish = 21, &
      k_restart = 22, k_gmres_max_it = 23, k_rtol = 24, k_precond = 25, k_forcing = 26, &
      k_gamma_alg = 27, k_enabled = 28, k_every = 29, k_flux = 30, k_alg_levels = 31, k_criteria = 32, &
      k_checks = 33, k_bound = 34, &
      k_output_file = 35, k_fields = 36, k_estimators = 37, k_history = 38, k_xdmf = 39, &
      k_adapt_tol = 40, k_theta = 41, k_max_steps = 42, k_max_vertices = 43

   !> Within a group, the order of the echo and of the "valid keys" lists.
   type(key_t), parameter :: keys(*) = [ &
      key_t(k_domain, group_mesh, 'domain', type_word), &
      key_t(k_mesh_file, group_mesh, 'file', type_path), &
      key_t(k_coarse_h, group_mesh, 'coarse_h', type_real), &
      key_t(k_levels, group_mesh, 'levels', type_int), &
      key_t(k_boundary_h, group_mesh, 'boundary_h', type_real), &
      key_t(k_mu1, group_problem, 'mu1', type_real), &
      key_t(k_mu2, group_problem, 'mu2', type_real), &
      key_t(k_f1, group_problem, 'f1', type_load), &
      key_t(k_f2, group_problem, 'f2', type_load), &
      key_t(k_g, group_problem, 'g', type_real), &
      key_t(k_exact, group_problem, 'exact', type_word), &
      key_t(k_f1_file, group_problem, 'f1_file', type_path), &
      key_t(k_f2_file, group_problem, 'f2_file', type_path), &
      key_t(k_cfun, group_newton, 'cfun', type_word), &
      key_t(k_linear, group_newton, 'linear', type_word), &
      key_t(k_newton_max_it, group_newton, 'max_it', type_int), &
      key_t(k_tol, group_newton, 'tol', type_real), &
      key_t(k_gamma_lin, group_newton, 'gamma_lin', type_real), &
      key_t(k_initial, group_newton, 'initial', type_word), &
      key_t(k_line_search, group_newton, 'line_search', type_word), &
      key_t(k_fb_finish, group_newton, 'fb_finish', type_word), &
      key_t(k_restart, group_gmres, 'restart', type_int), &
      key_t(k_gmres_max_it, group_gmres, 'max_it', type_int), &
      key_t(k_rtol, group_gmres, 'rtol', type_real), &
      key_t(k_precond, group_gmres, 'precond', type_word), &
      key_t(k_forcing, group_gmres, 'forcing', type_word), &
      key_t(k_gamma_alg, group_estimate, 'gamma_alg', type_real), &
      key_t(k_enabled, group_estimate, 'enabled', type_logical), &
      key_t(k_every, group_estimate, 'every', type_int), &
      key_t(k_flux, group_estimate, 'flux', type_word), &
      key_t(k_alg_levels, group_estimate, 'alg_levels', type_int), &
      key_t(k_criteria, group_estimate, 'criteria', type_word), &
      key_t(k_checks, group_estimate, 'checks', type_word), &
      key_t(k_bound, group_estimate, 'bound', type_word), &
      key_t(k_output_file, group_output, 'file', type_path), &
      key_t(k_fields, group_output, 'fields', type_logical), &
      key_t(k_estimators, group_output, 'estimators', type_logical), &
      key_t(k_history, group_output, 'history', type_logical), &
      key_t(k_xdmf, group_output, 'xdmf', type_logical), &
      key_t(k_adapt_tol, group_adapt, 'tol', type_real), &
      key_t(k_theta, group_adapt, 'theta', type_real), &
      key_t(k_max_steps, group_adapt, 'max_steps', type_int), &
      key_t(k_max_vertices, group_adapt, 'max_vertices', type_int)]
   integer, parameter :: n_keys = size(keys)

   !> Compile-time guards, through an invalid kind (-1) when they fail: every row sits at its
   !> own number, and every name is shorter than its field (a longer name, cut to the field,
   !> would fill it).
   integer(merge(kind(1), -1, keys(1)%id == 1 .and. all(keys(2:)%id - keys(:n_keys - 1)%id == 1))), &
      parameter :: rows_in_order = 0
   integer(merge(kind(1), -1, all(len_trim(keys%name) < name_len) .and. &
                  all(len_trim(group_names) < name_len))), parameter :: names_fit = 0

contains

   pure integer function find_group(name) result(gid)
      character(len=*), intent(in) :: name

      do gid = 1, n_groups
         if (group_names(gid) == name) return
      end do
      gid = 0
   end function find_group

   pure integer function find_key(gid, key) result(id)
      integer, intent(in) :: gid
      character(len=*), intent(in) :: key

      do id = 1, n_keys
         if (keys(id)%group == gid .and. keys(id)%name == key) return
      end do
      id = 0
   end function find_key

   !> The name of key `id`, and of its group.
   pure function key_name(id) result(name)
      integer, intent(in) :: id
      character(len=:), allocatable :: name

      name = trim(keys(id)%name)
   end function key_name

   pure function group_name(id) result(name)
      integer, intent(in) :: id
      character(len=:), allocatable :: name

      name = trim(group_names(keys(id)%group))
   end function group_name

   pure function group_list() result(list)
      character(len=:), allocatable :: list

      integer :: gid

      list = trim(group_names(1))
      do gid = 2, n_groups
         list = list//', '//trim(group_names(gid))
      end do
   end function group_list

   pure function key_list(gid) result(list)
      integer, intent(in) :: gid
      character(len=:), allocatable :: list

      integer :: id

      list = ''
      do id = 1, n_keys
         if (keys(id)%group /= gid) cycle
         if (len(list) > 0) list = list//', '
         list = list//trim(keys(id)%name)
      end do
   end function key_list
end module twomem_input_keys
