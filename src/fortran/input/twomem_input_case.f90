!> The case description: one derived type per namelist group of the case file, with the
!> documented defaults as default initialization. A word is held as its kind
!> (`twomem_base_options`), which loading resolves and validation checks
!> (`twomem_input_options`), so no word travels past the input. Text components (file names,
!> formulas) have the fixed length `config_len` so that defaults can be default initialization;
!> the loader rejects longer values rather than truncating them (`twomem_input_config`).
module twomem_input_case
   use twomem_base_kinds, only: dp
   use twomem_base_options, only: domain_disk, exact_none, c_function_min, method_adaptive, initial_nested, &
      line_search_auto, fb_finish_active_set, precond_mg, forcing_finish, flux_rt1, criteria_global, checks_predicted, bound_paper
   implicit none
   private

   public :: config_t, mesh_config_t, problem_config_t, newton_config_t, gmres_config_t
   public :: estimate_config_t, output_config_t, adapt_config_t, config_len

   !> length of every text component (words and file names)
   integer, parameter :: config_len = 256

   type :: mesh_config_t
      !> domain_disk, domain_square or domain_gmsh
      integer :: domain = domain_disk
      character(len=config_len) :: file = ''
      real(dp) :: coarse_h = 0.25_dp
      integer :: levels = 4
      !> boundary vertex spacing of the coarse disk; 0 = automatic (from the finest level)
      real(dp) :: boundary_h = 0.0_dp
   end type mesh_config_t

   type :: problem_config_t
      real(dp) :: mu1 = 1.0_dp
      real(dp) :: mu2 = 1.0_dp
      !> the loads when they are numbers (f1_formula, f2_formula empty)
      real(dp) :: f1 = -0.25_dp
      real(dp) :: f2 = 0.25_dp
      real(dp) :: g = 0.05_dp
      !> exact_none, exact_radial or exact_bbbv
      integer :: exact = exact_none
      !> the loads as formulas of x, y, r (`twomem_input_formula`); '' when they are numbers
      character(len=config_len) :: f1_formula = ''
      character(len=config_len) :: f2_formula = ''
      !> nodal loads from HDF5, 'FILE:DATASET'; '' when not used
      character(len=config_len) :: f1_file = ''
      character(len=config_len) :: f2_file = ''
   end type problem_config_t

   type :: newton_config_t
      !> c_function_min or c_function_fb
      integer :: cfun = c_function_min
      !> method_direct, method_gmres or method_adaptive
      integer :: linear = method_adaptive
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
      real(dp) :: gamma_lin = 0.3_dp
      !> initial_paper: (u1, u2, λ) = (g, 0, 0); initial_nested: solve on each coarser level first
      integer :: initial = initial_nested
      !> line_search_auto (on for fb, off for min), line_search_on, line_search_off
      integer :: line_search = line_search_auto
      !> fb_finish_active_set: Fischer–Burmeister finishes with Newton-min steps once its
      !> contact set settles; fb_finish_none: FB throughout (the paper's method)
      integer :: fb_finish = fb_finish_active_set
   end type newton_config_t

   type :: gmres_config_t
      integer :: restart = 30
      integer :: max_it = 5000
      real(dp) :: rtol = 1.0e-10_dp
      !> precond_mg (block elimination, one multigrid V-cycle per SPD block), precond_ilu0,
      !> precond_jacobi, precond_none
      integer :: precond = precond_mg
      !> forcing_paper: stop when the relative algebraic residual ≤ the relative linearization
      !> residual (the paper's inexact method); forcing_finish: the same until the iterate takes
      !> the step's branches; forcing_fixed: at gmres.rtol
      integer :: forcing = forcing_finish
   end type gmres_config_t

   type :: estimate_config_t
      real(dp) :: gamma_alg = 0.3_dp
      logical :: enabled = .true.
      !> ν: estimators and history rows every ν GMRES iterations; 0 = automatic (3 with the
      !> multigrid preconditioner, which needs a handful of iterations per Newton step, and
      !> the paper's 10 otherwise)
      integer :: every = 0
      !> flux reconstruction space: flux_rt1 (the paper) or flux_rt0
      integer :: flux = flux_rt1
      !> how many of the finest meshes the multilevel algebraic flux uses (the paper: 3)
      integer :: alg_levels = 3
      !> adaptive stopping: criteria_global (paper eq. (63)) or criteria_local (eq. (64),
      !> implies the global)
      integer :: criteria = criteria_global
      !> how much of the estimators the adaptive method's checks compute: checks_predicted (η_lin
      !> first, then η_disc and the rest only while Newton's test can hold) or checks_all (the paper)
      integer :: checks = checks_predicted
      !> bound_paper (the paper's (41)), bound_root or bound_sharp (docs/method.md §3)
      integer :: bound = bound_paper
   end type estimate_config_t

   type :: output_config_t
      !> '' in the input means `results/<case>.h5`; resolved by `load_config`
      character(len=config_len) :: file = ''
      logical :: fields = .true.
      logical :: estimators = .true.
      logical :: history = .true.
      logical :: xdmf = .true.
   end type output_config_t

   !> Adaptive refinement (SOLVE → ESTIMATE → MARK → REFINE), off while tol = 0
   type :: adapt_config_t
      !> the target for η; 0: no adaptation (one solve on the configured mesh)
      real(dp) :: tol = 0.0_dp
      !> Dörfler's bulk fraction θ: the marked triangles carry θ of Σ η_disc,K²
      real(dp) :: theta = 0.5_dp
      !> solves at most, the first mesh's included
      integer :: max_steps = 30
      !> no mesh with more vertices is solved on
      integer :: max_vertices = 1000000
   end type adapt_config_t

   type :: config_t
      !> base name of the case file without directory and extension
      character(len=config_len) :: case_name = ''
      !> path of the case file as given
      character(len=config_len) :: source = ''
      type(mesh_config_t) :: mesh
      type(problem_config_t) :: problem
      type(newton_config_t) :: newton
      type(gmres_config_t) :: gmres
      type(estimate_config_t) :: estimate
      type(output_config_t) :: output
      type(adapt_config_t) :: adapt
   end type config_t
end module twomem_input_case
