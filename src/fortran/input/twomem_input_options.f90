!> The words of the case file's word keys: one table of rows (key, word, kind, one line of help),
!> the words of each key in the order that messages list them. Loading turns a word into its
!> kind (`twomem_base_options`) by this table, the echo turns the kind back into the word, and
!> validation names the valid words from it; past validation no word is compared anywhere. A new
!> word is a new row here and a new kind there. Words and help lines have fixed widths, checked
!> at compile time.
module twomem_input_options
   use twomem_base_options, only: domain_disk, domain_square, domain_gmsh, exact_none, exact_radial, exact_bbbv, &
      c_function_min, c_function_fb, method_direct, method_gmres, method_adaptive, initial_paper, initial_nested, &
      line_search_auto, line_search_on, line_search_off, fb_finish_active_set, fb_finish_none, &
      precond_mg, precond_ilu0, precond_jacobi, precond_none, forcing_finish, forcing_paper, forcing_fixed, &
      flux_rt1, flux_rt0, criteria_global, criteria_local, checks_predicted, checks_all, &
      bound_paper, bound_root, bound_sharp
   use twomem_input_values, only: quote
   use twomem_input_keys, only: k_domain, k_exact, k_cfun, k_linear, k_initial, k_line_search, k_fb_finish, &
      k_precond, k_forcing, k_flux, k_criteria, k_checks, k_bound
   implicit none
   private

   public :: option_word_t, option_words, kind_of_word, word_of_kind, has_kind, word_list

   integer, parameter :: word_len = 16, help_len = 96

   type :: option_word_t
      !> the key (k_*) whose value the word is
      integer :: key
      character(len=word_len) :: word
      integer :: kind
      character(len=help_len) :: help
   end type option_word_t

   type(option_word_t), parameter :: option_words(*) = [ &
      option_word_t(k_domain, 'disk', domain_disk, 'the unit disk, graded towards its circle'), &
      option_word_t(k_domain, 'square', domain_square, 'the square (-1,1)^2'), &
      option_word_t(k_domain, 'gmsh', domain_gmsh, 'the Gmsh mesh of mesh.file'), &
      option_word_t(k_exact, 'none', exact_none, 'no closed-form solution'), &
      option_word_t(k_exact, 'radial', exact_radial, 'constant data on the unit disk, a radial solution'), &
      option_word_t(k_exact, 'bbbv', exact_bbbv, 'the paper''s case on the unit disk, with its own data'), &
      option_word_t(k_cfun, 'min', c_function_min, 'Newton-min: C(a, b) = min(a, b)'), &
      option_word_t(k_cfun, 'fb', c_function_fb, 'Fischer-Burmeister: C(a, b) = sqrt(a^2 + b^2) - a - b'), &
      option_word_t(k_linear, 'direct', method_direct, 'UMFPACK: the exact method'), &
      option_word_t(k_linear, 'gmres', method_gmres, 'preconditioned GMRES, stopped by gmres.forcing'), &
      option_word_t(k_linear, 'adaptive', method_adaptive, 'GMRES and Newton stopped by the estimators'), &
      option_word_t(k_initial, 'paper', initial_paper, '(u1, u2, lambda) = (g, 0, 0) on the finest mesh'), &
      option_word_t(k_initial, 'nested', initial_nested, 'nested iteration from the coarsest level'), &
      option_word_t(k_line_search, 'auto', line_search_auto, 'on for Fischer-Burmeister, off for Newton-min'), &
      option_word_t(k_line_search, 'on', line_search_on, 'backtracking on the merit'), &
      option_word_t(k_line_search, 'off', line_search_off, 'full steps'), &
      option_word_t(k_fb_finish, 'active_set', fb_finish_active_set, &
                    'Newton-min steps once the contact set of Fischer-Burmeister settles'), &
      option_word_t(k_fb_finish, 'none', fb_finish_none, 'Fischer-Burmeister at every step (the paper)'), &
      option_word_t(k_precond, 'mg', precond_mg, 'block elimination, one multigrid V-cycle per SPD block'), &
      option_word_t(k_precond, 'ilu0', precond_ilu0, 'ILU(0) of the Newton matrix (one rank)'), &
      option_word_t(k_precond, 'jacobi', precond_jacobi, 'the diagonal of the Newton matrix (one rank)'), &
      option_word_t(k_precond, 'none', precond_none, 'no preconditioner (one rank)'), &
      option_word_t(k_forcing, 'finish', forcing_finish, 'the paper''s, then on to newton.tol on the step''s branches'), &
      option_word_t(k_forcing, 'paper', forcing_paper, 'algebraic below linearization residual (the paper)'), &
      option_word_t(k_forcing, 'fixed', forcing_fixed, 'GMRES to gmres.rtol'), &
      option_word_t(k_flux, 'rt1', flux_rt1, 'Raviart-Thomas of degree 1 (the paper)'), &
      option_word_t(k_flux, 'rt0', flux_rt0, 'Raviart-Thomas of degree 0 (cheaper)'), &
      option_word_t(k_criteria, 'global', criteria_global, 'the paper''s global stopping criteria (63)'), &
      option_word_t(k_criteria, 'local', criteria_local, 'the local criteria (64) on every patch and element'), &
      option_word_t(k_checks, 'predicted', checks_predicted, 'eta_lin first, the rest while Newton''s test can hold'), &
      option_word_t(k_checks, 'all', checks_all, 'every estimator at every check (the paper)'), &
      option_word_t(k_bound, 'paper', bound_paper, 'the bound (41) as the paper states it'), &
      option_word_t(k_bound, 'root', bound_root, 'the exact root of the proof''s last inequality, triangle Poincare'), &
      option_word_t(k_bound, 'sharp', bound_sharp, 'root, and the contact multiplier moved into the contact zone')]

   !> Compile-time guard, through an invalid kind (-1) when it fails: every word and help line
   !> is shorter than its field (a longer one, cut to the field, would fill it).
   integer(merge(kind(1), -1, all(len_trim(option_words%word) < word_len) .and. &
                  all(len_trim(option_words%help) < help_len))), parameter :: words_fit = 0

contains

   !> The kind of `word` for key `id`; 0 when it is none of the key's words.
   pure integer function kind_of_word(id, word) result(kind)
      integer, intent(in) :: id
      character(len=*), intent(in) :: word

      integer :: i

      kind = 0
      do i = 1, size(option_words)
         if (option_words(i)%key == id .and. option_words(i)%word == word) then
            kind = option_words(i)%kind
            return
         end if
      end do
   end function kind_of_word

   !> The word of kind `kind` for key `id` ('' for none).
   pure function word_of_kind(id, kind) result(word)
      integer, intent(in) :: id, kind
      character(len=:), allocatable :: word

      integer :: i

      word = ''
      do i = 1, size(option_words)
         if (option_words(i)%key == id .and. option_words(i)%kind == kind) then
            word = trim(option_words(i)%word)
            return
         end if
      end do
   end function word_of_kind

   !> Whether `kind` is one of key `id`'s.
   pure logical function has_kind(id, kind)
      integer, intent(in) :: id, kind

      has_kind = any(option_words%key == id .and. option_words%kind == kind)
   end function has_kind

   !> The words of key `id`, quoted, in table order: "'min', 'fb'".
   pure function word_list(id) result(list)
      integer, intent(in) :: id
      character(len=:), allocatable :: list

      integer :: i

      list = ''
      do i = 1, size(option_words)
         if (option_words(i)%key /= id) cycle
         if (len(list) > 0) list = list//', '
         list = list//quote(trim(option_words(i)%word))
      end do
   end function word_list
end module twomem_input_options
