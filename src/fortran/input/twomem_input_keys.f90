!> The keys of the case file: one row per key (its group, name and kind of value), in the
!> order of the documentation and of the echoed input, and the lookups by name. Loading,
!> validation and the echo all go by this table, so a key is added in one place.
module twomem_input_keys
   implicit none
   private

   public :: n_groups, n_keys, group_names, key_group, key_names, key_kinds
   public :: kind_word, kind_path, kind_real, kind_int, kind_logical, kind_load
   public :: k_domain, k_mesh_file, k_coarse_h, k_levels, k_mu1, k_mu2, k_f1, k_f2, k_g, k_exact, &
             k_cfun, k_linear, k_newton_max_it, k_tol, k_gamma_lin, k_restart, k_gmres_max_it, k_rtol, &
             k_precond, k_gamma_alg, k_enabled, k_output_file, k_fields, k_estimators, k_history, k_xdmf, &
             k_boundary_h, k_initial, k_line_search, k_forcing, k_every, k_flux, k_alg_levels, k_criteria, &
             k_f1_file, k_f2_file, k_fb_finish, k_checks
   public :: find_group, find_key, group_list, key_list

   integer, parameter :: n_groups = 6, n_keys = 38
   character(len=*), parameter :: group_names(n_groups) = [character(len=8) :: &
      'mesh', 'problem', 'newton', 'gmres', 'estimate', 'output']
   !> kind_load: a real number, or a formula (quoted in a file; a bare override that is not a
   !> number is a formula too)
   integer, parameter :: kind_word = 1, kind_path = 2, kind_real = 3, kind_int = 4, kind_logical = 5, &
      kind_load = 6
   integer, parameter :: k_domain = 1, k_mesh_file = 2, k_coarse_h = 3, k_levels = 4, &
      k_mu1 = 5, k_mu2 = 6, k_f1 = 7, k_f2 = 8, k_g = 9, k_exact = 10, &
      k_cfun = 11, k_linear = 12, k_newton_max_it = 13, k_tol = 14, k_gamma_lin = 15, &
      k_restart = 16, k_gmres_max_it = 17, k_rtol = 18, k_precond = 19, &
      k_gamma_alg = 20, k_enabled = 21, &
      k_output_file = 22, k_fields = 23, k_estimators = 24, k_history = 25, k_xdmf = 26, &
      k_boundary_h = 27, k_initial = 28, k_line_search = 29, k_forcing = 30, k_every = 31, &
      k_flux = 32, k_alg_levels = 33, k_criteria = 34, k_f1_file = 35, k_f2_file = 36, k_fb_finish = 37, &
      k_checks = 38
   integer, parameter :: key_group(n_keys) = [1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 3, 3, 3, 3, 3, &
                                              4, 4, 4, 4, 5, 5, 6, 6, 6, 6, 6, 1, 3, 3, 4, 5, 5, 5, 5, &
                                              2, 2, 3, 5]
   character(len=*), parameter :: key_names(n_keys) = [character(len=12) :: &
      'domain', 'file', 'coarse_h', 'levels', &
      'mu1', 'mu2', 'f1', 'f2', 'g', 'exact', &
      'cfun', 'linear', 'max_it', 'tol', 'gamma_lin', &
      'restart', 'max_it', 'rtol', 'precond', &
      'gamma_alg', 'enabled', &
      'file', 'fields', 'estimators', 'history', 'xdmf', 'boundary_h', &
      'initial', 'line_search', 'forcing', 'every', 'flux', 'alg_levels', 'criteria', 'f1_file', 'f2_file', &
      'fb_finish', 'checks']
   integer, parameter :: key_kinds(n_keys) = [kind_word, kind_path, kind_real, kind_int, &
      kind_real, kind_real, kind_load, kind_load, kind_real, kind_word, &
      kind_word, kind_word, kind_int, kind_real, kind_real, &
      kind_int, kind_int, kind_real, kind_word, &
      kind_real, kind_logical, &
      kind_path, kind_logical, kind_logical, kind_logical, kind_logical, kind_real, &
      kind_word, kind_word, kind_word, kind_int, kind_word, kind_int, kind_word, kind_path, kind_path, &
      kind_word, kind_word]

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
         if (key_group(id) == gid .and. key_names(id) == key) return
      end do
      id = 0
   end function find_key

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
         if (key_group(id) /= gid) cycle
         if (len(list) > 0) list = list//', '
         list = list//trim(key_names(id))
      end do
   end function key_list
end module twomem_input_keys
