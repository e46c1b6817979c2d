!> HDF5 files as twomem uses them: one `h5_file_t` per open file, datasets of `real(dp)` and
!> `integer(ip)` addressed by path (intermediate groups are created on the way), and scalar
!> attributes on the root, a group or a dataset. This is the only Fortran that talks to
!> src/c/twomem_hdf5.c: every failure comes back as an `exit_io` error whose message names the
!> file and object and carries HDF5's own explanation. Arrays keep Fortran's memory order and
!> are declared with their shape reversed, so `a(2, nv)` reads in h5py (and XDMF) as `(nv, 2)`
!> without a transposing copy. It knows no file layout and sits on the lowest level above base,
!> so that a reader of input data can use it as well as the result writer (`twomem_io_result`).
module twomem_hdf5_file
   use, intrinsic :: iso_c_binding, only: c_char, c_int, c_double, c_int64_t, c_size_t, c_null_char
   use twomem_base_kinds, only: dp, ip, i8
   use twomem_base_system, only: c_text
   use twomem_base_errors, only: error_t, make_error, exit_io
   implicit none
   private

   public :: h5_file_t

   !> Room for one HDF5 message; the C side truncates longer ones.
   integer, parameter :: msg_len = 2048

   type :: h5_file_t
      private
      integer(c_int64_t) :: id = -1_c_int64_t
      character(len=:), allocatable :: path
   contains
      procedure :: create => h5_create
      procedure :: open_read => h5_open_read
      procedure :: close => h5_close
      procedure :: is_open => h5_is_open
      procedure :: has => h5_has
      procedure :: has_attr => h5_has_attr
      procedure :: get_dims => h5_get_dims
      procedure, private :: write_real_1d, write_real_2d, write_int_1d, write_int_2d
      generic :: write_real => write_real_1d, write_real_2d
      generic :: write_int => write_int_1d, write_int_2d
      procedure, private :: read_real_1d, read_real_2d, read_int_1d, read_int_2d
      generic :: read_real => read_real_1d, read_real_2d
      generic :: read_int => read_int_1d, read_int_2d
      procedure, private :: write_attr_string, write_attr_real, write_attr_int
      generic :: write_attr => write_attr_string, write_attr_real, write_attr_int
      procedure, private :: read_attr_string, read_attr_real, read_attr_int
      generic :: read_attr => read_attr_string, read_attr_real, read_attr_int
      final :: h5_finalize
   end type h5_file_t

   interface
      integer(c_int) function c_create(path, fid, msg, cap) bind(C, name='twomem_h5_create')
         import :: c_char, c_int, c_int64_t, c_size_t
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int64_t), intent(out) :: fid
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_create

      integer(c_int) function c_open_read(path, fid, msg, cap) bind(C, name='twomem_h5_open_read')
         import :: c_char, c_int, c_int64_t, c_size_t
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int64_t), intent(out) :: fid
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_open_read

      integer(c_int) function c_close(fid, msg, cap) bind(C, name='twomem_h5_close')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_close

      integer(c_int) function c_exists(fid, path) bind(C, name='twomem_h5_exists')
         import :: c_char, c_int, c_int64_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
      end function c_exists

      integer(c_int) function c_attr_exists(fid, obj, name) bind(C, name='twomem_h5_attr_exists')
         import :: c_char, c_int, c_int64_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
      end function c_attr_exists

      integer(c_int) function c_write_double(fid, path, rank, dims, data, msg, cap) &
         bind(C, name='twomem_h5_write_double')
         import :: c_char, c_int, c_int64_t, c_size_t, c_double
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: rank
         integer(c_int64_t), intent(in) :: dims(*)
         real(c_double), intent(in) :: data(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_write_double

      integer(c_int) function c_write_int(fid, path, rank, dims, data, msg, cap) &
         bind(C, name='twomem_h5_write_int')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: rank
         integer(c_int64_t), intent(in) :: dims(*)
         integer(c_int), intent(in) :: data(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_write_int

      integer(c_int) function c_dims(fid, path, rank, dims, msg, cap) bind(C, name='twomem_h5_dims')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), intent(out) :: rank
         integer(c_int64_t), intent(out) :: dims(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_dims

      integer(c_int) function c_read_double(fid, path, rank, dims, data, msg, cap) &
         bind(C, name='twomem_h5_read_double')
         import :: c_char, c_int, c_int64_t, c_size_t, c_double
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: rank
         integer(c_int64_t), intent(in) :: dims(*)
         real(c_double), intent(out) :: data(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_read_double

      integer(c_int) function c_read_int(fid, path, rank, dims, data, msg, cap) &
         bind(C, name='twomem_h5_read_int')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: rank
         integer(c_int64_t), intent(in) :: dims(*)
         integer(c_int), intent(out) :: data(*)
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_read_int

      integer(c_int) function c_write_attr_string(fid, obj, name, value, len, msg, cap) &
         bind(C, name='twomem_h5_write_attr_string')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*), value(*)
         integer(c_int64_t), value :: len
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_write_attr_string

      integer(c_int) function c_write_attr_double(fid, obj, name, value, msg, cap) &
         bind(C, name='twomem_h5_write_attr_double')
         import :: c_char, c_int, c_int64_t, c_size_t, c_double
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         real(c_double), value :: value
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_write_attr_double

      integer(c_int) function c_write_attr_int(fid, obj, name, value, msg, cap) &
         bind(C, name='twomem_h5_write_attr_int')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         integer(c_int), value :: value
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_write_attr_int

      integer(c_int) function c_attr_string_len(fid, obj, name, len, msg, cap) &
         bind(C, name='twomem_h5_attr_string_len')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         integer(c_int64_t), intent(out) :: len
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_attr_string_len

      integer(c_int) function c_read_attr_string(fid, obj, name, value, len, msg, cap) &
         bind(C, name='twomem_h5_read_attr_string')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         character(kind=c_char), intent(out) :: value(*)
         integer(c_int64_t), value :: len
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_read_attr_string

      integer(c_int) function c_read_attr_double(fid, obj, name, value, msg, cap) &
         bind(C, name='twomem_h5_read_attr_double')
         import :: c_char, c_int, c_int64_t, c_size_t, c_double
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         real(c_double), intent(out) :: value
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_read_attr_double

      integer(c_int) function c_read_attr_int(fid, obj, name, value, msg, cap) &
         bind(C, name='twomem_h5_read_attr_int')
         import :: c_char, c_int, c_int64_t, c_size_t
         integer(c_int64_t), value :: fid
         character(kind=c_char), intent(in) :: obj(*), name(*)
         integer(c_int), intent(out) :: value
         character(kind=c_char), intent(out) :: msg(*)
         integer(c_size_t), value :: cap
      end function c_read_attr_int
   end interface

contains

   !> Create `path`, truncating an existing file; a file already open in `self` is closed first.
   subroutine h5_create(self, path, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      call self%close(err)
      if (allocated(err)) return
      if (c_create(path//c_null_char, self%id, msg, len(msg, c_size_t)) /= 0) then
         self%id = -1_c_int64_t
         call make_error(err, exit_io, path, c_text(msg))
         return
      end if
      self%path = path
   end subroutine h5_create

   subroutine h5_open_read(self, path, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      call self%close(err)
      if (allocated(err)) return
      if (c_open_read(path//c_null_char, self%id, msg, len(msg, c_size_t)) /= 0) then
         self%id = -1_c_int64_t
         call make_error(err, exit_io, path, c_text(msg))
         return
      end if
      self%path = path
   end subroutine h5_open_read

   !> Flush and close; closing a file that is not open does nothing. Only a successful close
   !> guarantees that everything written is on disk.
   subroutine h5_close(self, err)
      class(h5_file_t), intent(inout) :: self
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int) :: status

      if (.not. self%is_open()) return
      status = c_close(self%id, msg, len(msg, c_size_t))
      self%id = -1_c_int64_t
      if (status /= 0) call make_error(err, exit_io, self%path, c_text(msg))
   end subroutine h5_close

   !> A file left open by an early return on error is closed when its variable goes away.
   subroutine h5_finalize(self)
      type(h5_file_t), intent(inout) :: self

      character(len=msg_len) :: msg
      integer(c_int) :: status

      if (self%id < 0) return
      status = c_close(self%id, msg, len(msg, c_size_t))
      self%id = -1_c_int64_t
   end subroutine h5_finalize

   logical function h5_is_open(self)
      class(h5_file_t), intent(in) :: self

      h5_is_open = self%id >= 0
   end function h5_is_open

   !> Whether a group or dataset exists at `path` ('/' always does).
   logical function h5_has(self, path)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: path

      h5_has = .false.
      if (self%is_open()) h5_has = c_exists(self%id, path//c_null_char) == 1
   end function h5_has

   logical function h5_has_attr(self, obj_path, name)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: obj_path, name

      h5_has_attr = .false.
      if (self%is_open()) h5_has_attr = c_attr_exists(self%id, obj_path//c_null_char, name//c_null_char) == 1
   end function h5_has_attr

   !> Dimensions of a dataset as HDF5 and h5py see them (row-major: the reverse of the
   !> Fortran shape that wrote it).
   subroutine h5_get_dims(self, dset_path, dims, err)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: dset_path
      integer(i8), allocatable, intent(out) :: dims(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: got(7)
      integer(c_int) :: rank

      if (.not. ready(self, dset_path, err)) return
      if (c_dims(self%id, dset_path//c_null_char, rank, got, msg, len(msg, c_size_t)) /= 0) then
         call fail(self, dset_path, msg, err)
         return
      end if
      dims = int(got(1:rank), i8)
   end subroutine h5_get_dims

   ! ---- datasets --------------------------------------------------------------------------

   subroutine write_real_1d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      real(dp), intent(in) :: array(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, dset_path, err)) return
      if (c_write_double(self%id, dset_path//c_null_char, 1_c_int, [size(array, kind=c_int64_t)], &
                         array, msg, len(msg, c_size_t)) /= 0) call fail(self, dset_path, msg, err)
   end subroutine write_real_1d

   subroutine write_real_2d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      real(dp), intent(in) :: array(:, :)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, dset_path, err)) return
      if (c_write_double(self%id, dset_path//c_null_char, 2_c_int, h5_dims(shape(array, kind=c_int64_t)), &
                         array, msg, len(msg, c_size_t)) /= 0) call fail(self, dset_path, msg, err)
   end subroutine write_real_2d

   subroutine write_int_1d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      integer(ip), intent(in) :: array(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, dset_path, err)) return
      if (c_write_int(self%id, dset_path//c_null_char, 1_c_int, [size(array, kind=c_int64_t)], &
                      array, msg, len(msg, c_size_t)) /= 0) call fail(self, dset_path, msg, err)
   end subroutine write_int_1d

   subroutine write_int_2d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      integer(ip), intent(in) :: array(:, :)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, dset_path, err)) return
      if (c_write_int(self%id, dset_path//c_null_char, 2_c_int, h5_dims(shape(array, kind=c_int64_t)), &
                      array, msg, len(msg, c_size_t)) /= 0) call fail(self, dset_path, msg, err)
   end subroutine write_int_2d

   subroutine read_real_1d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      real(dp), allocatable, intent(out) :: array(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: dims(1)

      call dataset_dims(self, dset_path, dims, err)
      if (allocated(err)) return
      allocate (array(dims(1)))
      if (c_read_double(self%id, dset_path//c_null_char, 1_c_int, dims, array, msg, len(msg, c_size_t)) /= 0) &
         call fail(self, dset_path, msg, err)
   end subroutine read_real_1d

   subroutine read_real_2d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      real(dp), allocatable, intent(out) :: array(:, :)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: dims(2)

      call dataset_dims(self, dset_path, dims, err)
      if (allocated(err)) return
      allocate (array(dims(2), dims(1)))
      if (c_read_double(self%id, dset_path//c_null_char, 2_c_int, dims, array, msg, len(msg, c_size_t)) /= 0) &
         call fail(self, dset_path, msg, err)
   end subroutine read_real_2d

   subroutine read_int_1d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      integer(ip), allocatable, intent(out) :: array(:)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: dims(1)

      call dataset_dims(self, dset_path, dims, err)
      if (allocated(err)) return
      allocate (array(dims(1)))
      if (c_read_int(self%id, dset_path//c_null_char, 1_c_int, dims, array, msg, len(msg, c_size_t)) /= 0) &
         call fail(self, dset_path, msg, err)
   end subroutine read_int_1d

   subroutine read_int_2d(self, dset_path, array, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: dset_path
      integer(ip), allocatable, intent(out) :: array(:, :)
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: dims(2)

      call dataset_dims(self, dset_path, dims, err)
      if (allocated(err)) return
      allocate (array(dims(2), dims(1)))
      if (c_read_int(self%id, dset_path//c_null_char, 2_c_int, dims, array, msg, len(msg, c_size_t)) /= 0) &
         call fail(self, dset_path, msg, err)
   end subroutine read_int_2d

   !> HDF5 dims of a dataset whose rank must be size(dims).
   subroutine dataset_dims(self, dset_path, dims, err)
      type(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: dset_path
      integer(c_int64_t), intent(out) :: dims(:)
      type(error_t), allocatable, intent(out) :: err

      integer(i8), allocatable :: got(:)
      character(len=64) :: text

      dims = 0
      call self%get_dims(dset_path, got, err)
      if (allocated(err)) return
      if (size(got) /= size(dims)) then
         write (text, '("dataset has rank ",i0,", expected ",i0)') size(got), size(dims)
         call make_error(err, exit_io, self%path//':'//dset_path, trim(text))
         return
      end if
      dims = int(got, c_int64_t)
   end subroutine dataset_dims

   ! ---- attributes ------------------------------------------------------------------------

   !> Stored as a variable-length UTF-8 string, which h5py returns as `str`.
   subroutine write_attr_string(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name, value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, obj_path, err)) return
      if (c_write_attr_string(self%id, obj_path//c_null_char, name//c_null_char, value, &
                              len(value, c_int64_t), msg, len(msg, c_size_t)) /= 0) &
         call fail(self, attr_where(obj_path, name), msg, err)
   end subroutine write_attr_string

   subroutine write_attr_real(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name
      real(dp), intent(in) :: value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, obj_path, err)) return
      if (c_write_attr_double(self%id, obj_path//c_null_char, name//c_null_char, value, msg, &
                              len(msg, c_size_t)) /= 0) call fail(self, attr_where(obj_path, name), msg, err)
   end subroutine write_attr_real

   subroutine write_attr_int(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name
      integer, intent(in) :: value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg

      if (.not. ready(self, obj_path, err)) return
      if (c_write_attr_int(self%id, obj_path//c_null_char, name//c_null_char, int(value, c_int), msg, &
                           len(msg, c_size_t)) /= 0) call fail(self, attr_where(obj_path, name), msg, err)
   end subroutine write_attr_int

   !> Reads variable- and fixed-length strings alike (files written by h5py use either).
   subroutine read_attr_string(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name
      character(len=:), allocatable, intent(out) :: value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int64_t) :: n

      if (.not. ready(self, obj_path, err)) return
      if (c_attr_string_len(self%id, obj_path//c_null_char, name//c_null_char, n, msg, &
                            len(msg, c_size_t)) /= 0) then
         call fail(self, attr_where(obj_path, name), msg, err)
         return
      end if
      allocate (character(len=n) :: value)
      if (c_read_attr_string(self%id, obj_path//c_null_char, name//c_null_char, value, n, msg, &
                             len(msg, c_size_t)) /= 0) call fail(self, attr_where(obj_path, name), msg, err)
   end subroutine read_attr_string

   subroutine read_attr_real(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name
      real(dp), intent(out) :: value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      real(c_double) :: got

      value = 0.0_dp
      if (.not. ready(self, obj_path, err)) return
      if (c_read_attr_double(self%id, obj_path//c_null_char, name//c_null_char, got, msg, &
                             len(msg, c_size_t)) /= 0) then
         call fail(self, attr_where(obj_path, name), msg, err)
      else
         value = real(got, dp)
      end if
   end subroutine read_attr_real

   subroutine read_attr_int(self, obj_path, name, value, err)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: obj_path, name
      integer, intent(out) :: value
      type(error_t), allocatable, intent(out) :: err

      character(len=msg_len) :: msg
      integer(c_int) :: got

      value = 0
      if (.not. ready(self, obj_path, err)) return
      if (c_read_attr_int(self%id, obj_path//c_null_char, name//c_null_char, got, msg, &
                          len(msg, c_size_t)) /= 0) then
         call fail(self, attr_where(obj_path, name), msg, err)
      else
         value = int(got)
      end if
   end subroutine read_attr_int

   ! ---- helpers ---------------------------------------------------------------------------

   !> Fortran shape -> HDF5 dims: the same memory, read row-major.
   pure function h5_dims(fortran_shape) result(dims)
      integer(c_int64_t), intent(in) :: fortran_shape(:)
      integer(c_int64_t) :: dims(size(fortran_shape))

      dims = fortran_shape(size(fortran_shape):1:-1)
   end function h5_dims

   logical function ready(self, object, err)
      type(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: object
      type(error_t), allocatable, intent(out) :: err

      ready = self%is_open()
      if (.not. ready) call make_error(err, exit_io, object, 'HDF5 file is not open')
   end function ready

   subroutine fail(self, object, msg, err)
      type(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: object, msg
      type(error_t), allocatable, intent(out) :: err

      call make_error(err, exit_io, self%path//':'//object, c_text(msg))
   end subroutine fail

   pure function attr_where(obj_path, name) result(where)
      character(len=*), intent(in) :: obj_path, name
      character(len=:), allocatable :: where

      where = obj_path//' attribute '//name
   end function attr_where

end module twomem_hdf5_file
