!> The integer kinds of the case's option words: for every key whose value is a word
!> (newton.cfun, gmres.precond, ...), one named constant per word. The input layer parses each
!> word once into its kind (`twomem_input_options` holds the words, their kinds and a line of
!> help) and everything after validation passes kinds, so that a misspelt comparison is a
!> compile error instead of a branch silently never taken. The constants live here, below every
!> layer, because the input layer produces them and the numerical layers that act on them
!> (fem, estimate, newton) must not use the input layer. Every option's kinds start at 1: 0 is
!> no kind at all.
module twomem_base_options
   implicit none
   private

   public :: domain_disk, domain_square, domain_gmsh
   public :: exact_none, exact_radial, exact_bbbv
   public :: c_function_min, c_function_fb
   public :: method_direct, method_gmres, method_adaptive
   public :: initial_paper, initial_nested
   public :: line_search_auto, line_search_on, line_search_off
   public :: fb_finish_active_set, fb_finish_none
   public :: precond_mg, precond_ilu0, precond_jacobi, precond_none
   public :: forcing_paper, forcing_fixed, forcing_finish
   public :: flux_rt1, flux_rt0
   public :: criteria_global, criteria_local
   public :: checks_predicted, checks_all
   public :: bound_paper, bound_root, bound_sharp

   !> mesh.domain
   integer, parameter :: domain_disk = 1, domain_square = 2, domain_gmsh = 3
   !> problem.exact: no exact solution, or one of the verification cases
   integer, parameter :: exact_none = 1, exact_radial = 2, exact_bbbv = 3
   !> newton.cfun: Newton-min or Fischer–Burmeister
   integer, parameter :: c_function_min = 1, c_function_fb = 2
   !> newton.linear: UMFPACK, GMRES, or GMRES with the estimators' stopping tests
   integer, parameter :: method_direct = 1, method_gmres = 2, method_adaptive = 3
   !> newton.initial: (g, 0, 0) on the finest level, or nested iteration
   integer, parameter :: initial_paper = 1, initial_nested = 2
   !> newton.line_search
   integer, parameter :: line_search_auto = 1, line_search_on = 2, line_search_off = 3
   !> newton.fb_finish
   integer, parameter :: fb_finish_active_set = 1, fb_finish_none = 2
   !> gmres.precond
   integer, parameter :: precond_mg = 1, precond_ilu0 = 2, precond_jacobi = 3, precond_none = 4
   !> gmres.forcing
   integer, parameter :: forcing_paper = 1, forcing_fixed = 2, forcing_finish = 3
   !> estimate.flux: the Raviart–Thomas space of the flux reconstructions
   integer, parameter :: flux_rt1 = 1, flux_rt0 = 2
   !> estimate.criteria: the adaptive method's global or local stopping criteria
   integer, parameter :: criteria_global = 1, criteria_local = 2
   !> estimate.checks
   integer, parameter :: checks_predicted = 1, checks_all = 2
   !> estimate.bound: the paper's (41), its exact root with the triangles' Poincaré constant,
   !> and that with the redistributed contact multiplier (docs/method.md §3, *Sharper bounds*)
   integer, parameter :: bound_paper = 1, bound_root = 2, bound_sharp = 3
end module twomem_base_options
