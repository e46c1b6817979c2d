!> The rules a loaded case must satisfy (docs/input.md): ranges of numbers, allowed words, and
!> the rules across keys. The first violation is reported as bad input, one line naming where
!> the offending value came from (file and line, or the override), its group and key.
module twomem_input_rules
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use twomem_base_kinds, only: dp
   use twomem_base_errors, only: error_t, make_error, exit_bad_input, excerpt
   use twomem_base_text, only: int_text
   use twomem_input_namelist, only: string_t
   use twomem_input_values, only: format_real, quote
   use twomem_input_formula, only: formula_t
   use twomem_input_formula_parser, only: parse_formula
   use twomem_input_case, only: config_t
   use twomem_input_options, only: has_kind, word_of_kind, word_list
   use twomem_base_options, only: domain_disk, domain_square, domain_gmsh, exact_none
   use twomem_input_keys, only: key_name, group_name, k_domain, k_mesh_file, k_coarse_h, k_levels, k_boundary_h, &
      k_mu1, k_mu2, k_f1, k_f2, k_g, k_exact, k_f1_file, k_f2_file, k_cfun, k_linear, k_newton_max_it, k_tol, &
      k_gamma_lin, k_initial, k_line_search, k_fb_finish, k_restart, k_gmres_max_it, k_rtol, k_precond, &
      k_forcing, k_gamma_alg, k_every, k_flux, k_alg_levels, k_criteria, k_checks, k_bound, k_adapt_tol, k_theta, &
      k_max_steps, k_max_vertices
   implicit none
   private

   public :: validate

contains

   !> The rules of docs/input.md, in table order; the first violation is reported where the
   !> offending value came from (`origin`, per key). A word key whose kind is none of its
   !> key's is reported with the word as given (`given`, per key). Each check does nothing
   !> once `err` is set; past this one, every word key holds one of its kinds.
   subroutine validate(cfg, origin, given, err)
      type(config_t), intent(in) :: cfg
      type(string_t), intent(in) :: origin(:), given(:)
      type(error_t), allocatable, intent(out) :: err

      associate (m => cfg%mesh, p => cfg%problem, n => cfg%newton, g => cfg%gmres)
         call check_word(err, origin, given, k_domain, m%domain)
         call require(err, origin, k_domain, m%domain /= domain_gmsh .or. len_trim(m%file) > 0, &
                      "mesh.file must name the mesh when mesh.domain='gmsh'")
         call require(err, origin, k_mesh_file, m%domain == domain_gmsh .or. len_trim(m%file) == 0, &
                      "mesh.file is only read when mesh.domain='gmsh' (here domain='"//word_of_kind(k_domain, m%domain) &
                      //"')")
         call check_real(err, origin, k_coarse_h, m%coarse_h, ge=1.0e-4_dp, le=2.0_dp)
         call check_int(err, origin, k_levels, m%levels, 0, 12)
         call check_real(err, origin, k_boundary_h, m%boundary_h, ge=0.0_dp, le=2.0_dp)
         ! only once both are known to be finite: comparing a NaN traps in debug builds
         if (.not. allocated(err)) &
            call require(err, origin, k_boundary_h, m%boundary_h <= m%coarse_h, &
                         'mesh.boundary_h must not exceed mesh.coarse_h (0 chooses it automatically)')
         call require(err, origin, k_boundary_h, m%boundary_h == 0.0_dp .or. m%domain == domain_disk, &
                      "mesh.boundary_h is only used with mesh.domain='disk'")

         call check_real(err, origin, k_mu1, p%mu1, gt=0.0_dp)
         call check_real(err, origin, k_mu2, p%mu2, gt=0.0_dp)
         call check_load(err, origin, k_f1, p%f1, p%f1_formula)
         call check_load(err, origin, k_f2, p%f2, p%f2_formula)
         call check_real(err, origin, k_g, p%g, gt=0.0_dp)
         call check_word(err, origin, given, k_exact, p%exact)
         ! on a Gmsh mesh the mesh reader checks that its boundary lies on the unit circle
         call require(err, origin, k_exact, p%exact == exact_none .or. m%domain /= domain_square, &
                      "exact='"//word_of_kind(k_exact, p%exact)//"' needs the unit disk: mesh.domain='disk' or a "// &
                      "Gmsh mesh of the disk (here '"//word_of_kind(k_domain, m%domain)//"')")
         call check_load_file(err, origin, k_f1_file, p%f1_file, p%f1_formula, 'f1')
         call check_load_file(err, origin, k_f2_file, p%f2_file, p%f2_formula, 'f2')
         call require(err, origin, k_exact, p%exact == exact_none .or. len_trim(p%f1_formula // p%f2_formula // &
                      p%f1_file // p%f2_file) == 0, "exact='"//word_of_kind(k_exact, p%exact)//"' has its own loads: "// &
                      'f1 and f2 must be numbers, and f1_file, f2_file empty')

         call check_word(err, origin, given, k_cfun, n%cfun)
         call check_word(err, origin, given, k_linear, n%linear)
         call check_int(err, origin, k_newton_max_it, n%max_it, 1, 100000)
         call check_real(err, origin, k_tol, n%tol, gt=0.0_dp, lt=1.0_dp)
         call check_real(err, origin, k_gamma_lin, n%gamma_lin, gt=0.0_dp, le=1.0_dp)
         call check_word(err, origin, given, k_initial, n%initial)
         call check_word(err, origin, given, k_line_search, n%line_search)
         call check_word(err, origin, given, k_fb_finish, n%fb_finish)

         call check_int(err, origin, k_restart, g%restart, 1, 1000)
         call check_int(err, origin, k_gmres_max_it, g%max_it, 1, huge(1))
         call check_real(err, origin, k_rtol, g%rtol, gt=0.0_dp, lt=1.0_dp)
         call check_word(err, origin, given, k_precond, g%precond)
         call check_word(err, origin, given, k_forcing, g%forcing)
      end associate

      call check_real(err, origin, k_gamma_alg, cfg%estimate%gamma_alg, gt=0.0_dp, le=1.0_dp)
      call check_int(err, origin, k_every, cfg%estimate%every, 0, 100000)
      call check_word(err, origin, given, k_flux, cfg%estimate%flux)
      call check_int(err, origin, k_alg_levels, cfg%estimate%alg_levels, 1, 13)
      call check_word(err, origin, given, k_criteria, cfg%estimate%criteria)
      call check_word(err, origin, given, k_checks, cfg%estimate%checks)
      call check_word(err, origin, given, k_bound, cfg%estimate%bound)

      call check_real(err, origin, k_adapt_tol, cfg%adapt%tol, ge=0.0_dp)
      call check_real(err, origin, k_theta, cfg%adapt%theta, gt=0.0_dp, le=1.0_dp)
      call check_int(err, origin, k_max_steps, cfg%adapt%max_steps, 1, 1000)
      call check_int(err, origin, k_max_vertices, cfg%adapt%max_vertices, 3, huge(1))
      ! nodal loads are values on the vertices of the configured mesh, which refinement leaves
      if (.not. allocated(err)) &
         call require(err, origin, k_adapt_tol, cfg%adapt%tol == 0.0_dp .or. &
                      len_trim(cfg%problem%f1_file//cfg%problem%f2_file) == 0, &
                      'adaptive refinement needs loads defined everywhere (numbers or formulas): '// &
                      'problem.f1_file and problem.f2_file must be empty when adapt.tol > 0')
   end subroutine validate

   !> A load: finite when a number, parsed when a formula (the message gives the column).
   subroutine check_load(err, origin, id, x, formula)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      real(dp), intent(in) :: x
      character(len=*), intent(in) :: formula

      type(formula_t) :: f
      character(len=:), allocatable :: why
      integer :: where

      if (allocated(err)) return
      if (len_trim(formula) == 0) then
         call check_real(err, origin, id, x)
         return
      end if
      call parse_formula(trim(formula), f, where, why)
      if (allocated(why)) call fail(err, origin, id, 'formula '//quote(excerpt(trim(formula)))//': column '// &
                                    int_text(where)//': '//why)
   end subroutine check_load

   !> 'FILE:DATASET', and not together with a formula for the same load.
   subroutine check_load_file(err, origin, id, spec, formula, load)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      character(len=*), intent(in) :: spec, formula, load

      integer :: colon

      if (allocated(err) .or. len_trim(spec) == 0) return
      colon = index(spec, ':', back=.true.)
      if (colon <= 1 .or. colon >= len_trim(spec)) then
         call fail(err, origin, id, "must be 'FILE:DATASET', e.g. 'loads.h5:/"//load//"', got "// &
                   quote(excerpt(trim(spec))))
      else if (len_trim(formula) > 0) then
         call fail(err, origin, id, 'and a formula for '//load//' are both given: choose one')
      end if
   end subroutine check_load_file

   !> A rule across keys, blamed on key `id`: `<origin>: &group: what`.
   subroutine require(err, origin, id, ok, what)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      logical, intent(in) :: ok
      character(len=*), intent(in) :: what

      if (allocated(err) .or. ok) return
      call make_error(err, exit_bad_input, origin(id)%s//': &'//group_name(id), what)
   end subroutine require

   !> `<origin>: &group: key must be ...`
   subroutine fail(err, origin, id, what)
      type(error_t), allocatable, intent(out) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      character(len=*), intent(in) :: what

      call make_error(err, exit_bad_input, origin(id)%s//': &'//group_name(id), key_name(id)//' '//what)
   end subroutine fail

   !> Word key `id` holds one of its kinds (`kind`), or fails naming its words and the one given.
   subroutine check_word(err, origin, given, id, kind)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:), given(:)
      integer, intent(in) :: id, kind

      character(len=:), allocatable :: got

      if (allocated(err)) return
      if (has_kind(id, kind)) return
      got = ''
      if (allocated(given(id)%s)) got = given(id)%s
      call fail(err, origin, id, 'must be one of '//word_list(id)//', got '//quote(excerpt(got)))
   end subroutine check_word

   !> Finite, and within the bounds given (`gt`: >, `ge`: >=, `lt`: <, `le`: <=). Finiteness is
   !> tested first: comparing a NaN would trap in debug builds.
   subroutine check_real(err, origin, id, x, gt, ge, lt, le)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id
      real(dp), intent(in) :: x
      real(dp), intent(in), optional :: gt, ge, lt, le

      character(len=:), allocatable :: got

      if (allocated(err)) return
      got = ', got '//number_text(x)
      if (.not. ieee_is_finite(x)) then
         call fail(err, origin, id, 'must be finite'//got)
         return
      end if
      if (present(gt)) then
         if (.not. x > gt) call fail(err, origin, id, 'must be > '//number_text(gt)//got)
      end if
      if (allocated(err)) return
      if (present(ge)) then
         if (.not. x >= ge) call fail(err, origin, id, 'must be >= '//number_text(ge)//got)
      end if
      if (allocated(err)) return
      if (present(lt)) then
         if (.not. x < lt) call fail(err, origin, id, 'must be < '//number_text(lt)//got)
      end if
      if (allocated(err)) return
      if (present(le)) then
         if (.not. x <= le) call fail(err, origin, id, 'must be <= '//number_text(le)//got)
      end if
   end subroutine check_real

   !> A real for messages: as echoed, but whole numbers without '.0' ('must be > 0, got -1').
   function number_text(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s

      s = format_real(x)
      if (len(s) > 2) then
         if (s(len(s) - 1:) == '.0') s = s(1:len(s) - 2)
      end if
   end function number_text

   subroutine check_int(err, origin, id, n, lo, hi)
      type(error_t), allocatable, intent(inout) :: err
      type(string_t), intent(in) :: origin(:)
      integer, intent(in) :: id, n, lo, hi

      if (allocated(err)) return
      if (n < lo) then
         call fail(err, origin, id, 'must be >= '//int_text(lo)//', got '//int_text(n))
      else if (n > hi) then
         call fail(err, origin, id, 'must be <= '//int_text(hi)//', got '//int_text(n))
      end if
   end subroutine check_int
end module twomem_input_rules
