!> The case description: one derived type per namelist group of the case file, with the
!> documented defaults as default initialization. Text components have the fixed length
!> `config_len` so that defaults can be default initialization; the loader rejects longer
!> values rather than truncating them (`twomem_input_config`).
module twomem_input_case
   use twomem_base_kinds, only: dp
   implicit none
   private

   public :: config_t, mesh_config_t, problem_config_t, newton_config_t, gmres_config_t
   public :: estimate_config_t, output_config_t, config_len

   !> length of every text component (words and file names)
   integer, parameter :: config_len = 256

   type :: mesh_config_t
      character(len=config_len) :: domain = 'disk'
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
      character(len=config_len) :: exact = 'none'
      !> the loads as formulas of x, y, r (`twomem_input_formula`); '' when they are numbers
      character(len=config_len) :: f1_formula = ''
      character(len=config_len) :: f2_formula = ''
      !> nodal loads from HDF5, 'FILE:DATASET'; '' when not used
      character(len=config_len) :: f1_file = ''
      character(len=config_len) :: f2_file = ''
   end type problem_config_t

   type :: newton_config_t
      character(len=config_len) :: cfun = 'min'
      character(len=config_len) :: linear = 'adaptive'
      integer :: max_it = 100
      real(dp) :: tol = 1.0e-10_dp
      real(dp) :: gamma_lin = 0.3_dp
      !> 'paper': (u1, u2, λ) = (g, 0, 0); 'nested': solve on each coarser level first
      character(len=config_len) :: initial = 'nested'
      !> 'auto' (on for fb, off for min), 'on', 'off'
      character(len=config_len) :: line_search = 'auto'
      !> 'active_set': Fischer–Burmeister finishes with Newton-min steps once its contact set
      !> settles; 'none': FB throughout (the paper's method)
      character(len=config_len) :: fb_finish = 'active_set'
   end type newton_config_t

   type :: gmres_config_t
      integer :: restart = 30
      integer :: max_it = 5000
      real(dp) :: rtol = 1.0e-10_dp
      !> 'mg' (block elimination, one multigrid V-cycle per SPD block), 'ilu0', 'jacobi', 'none'
      character(len=config_len) :: precond = 'mg'
      !> 'paper': stop when the relative algebraic residual ≤ the relative linearization
      !> residual (the paper's inexact method); 'fixed': at gmres.rtol
      character(len=config_len) :: forcing = 'finish'
   end type gmres_config_t

   type :: estimate_config_t
      real(dp) :: gamma_alg = 0.3_dp
      logical :: enabled = .true.
      !> ν: estimators and history rows every ν GMRES iterations; 0 = automatic (3 with the
      !> multigrid preconditioner, which needs a handful of iterations per Newton step, and
      !> the paper's 10 otherwise)
      integer :: every = 0
      !> flux reconstruction space: 'rt1' (the paper) or 'rt0'
      character(len=config_len) :: flux = 'rt1'
      !> how many of the finest meshes the multilevel algebraic flux uses (the paper: 3)
      integer :: alg_levels = 3
      !> adaptive stopping: 'global' (paper eq. (63)) or 'local' (eq. (64), implies the global)
      character(len=config_len) :: criteria = 'global'
      !> how much of the estimators the adaptive method's checks compute: 'predicted' (η_lin
      !> first, then η_disc and the rest only while Newton's test can hold) or 'all' (the paper)
      character(len=config_len) :: checks = 'predicted'
   end type estimate_config_t

   type :: output_config_t
      !> '' in the input means `results/<case>.h5`; resolved by `load_config`
      character(len=config_len) :: file = ''
      logical :: fields = .true.
      logical :: estimators = .true.
      logical :: history = .true.
      logical :: xdmf = .true.
   end type output_config_t

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
   end type config_t
end module twomem_input_case
