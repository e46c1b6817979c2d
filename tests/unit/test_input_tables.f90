!> Tests of the tables the case input goes by: the key table (every key found by its group and
!> name) and the option words (every word of a word key, its kind unique within the key and
!> read back to the same word), so that a row added later cannot shadow or lose another.
module test_input_tables
   use twomem_input_keys, only: keys, n_keys, n_groups, find_key, type_word, type_load
   use twomem_input_options, only: option_words, kind_of_word, word_of_kind, has_kind
   use twomem_testing, only: unittest_t, new_unittest, check, error_t
   implicit none
   private

   public :: collect_input_tables

contains

   subroutine collect_input_tables(tests)
      type(unittest_t), allocatable, intent(out) :: tests(:)

      tests = [new_unittest('every_key_found_by_its_name', test_keys), &
               new_unittest('option_words_read_back', test_option_words)]
   end subroutine collect_input_tables

   subroutine test_keys(err)
      type(error_t), allocatable, intent(out) :: err

      integer :: id

      do id = 1, n_keys
         associate (key => keys(id))
            call check(err, key%group >= 1 .and. key%group <= n_groups, 'group of '//trim(key%name))
            call check(err, key%type >= type_word .and. key%type <= type_load, 'type of '//trim(key%name))
            call check(err, find_key(key%group, trim(key%name)) == id, 'found by its name: '//trim(key%name))
         end associate
         if (allocated(err)) return
      end do
   end subroutine test_keys

   subroutine test_option_words(err)
      type(error_t), allocatable, intent(out) :: err

      integer :: i, j, id

      do i = 1, size(option_words)
         associate (w => option_words(i))
            call check(err, keys(w%key)%type == type_word, trim(w%word)//' belongs to a word key')
            call check(err, w%kind >= 1, trim(w%word)//': kinds start at 1, 0 is no word')
            call check(err, kind_of_word(w%key, trim(w%word)) == w%kind, trim(w%word)//' read to its kind')
            call check(err, word_of_kind(w%key, w%kind) == trim(w%word), trim(w%word)//' written from its kind')
            do j = 1, i - 1
               if (option_words(j)%key /= w%key) cycle
               call check(err, option_words(j)%kind /= w%kind .and. option_words(j)%word /= w%word, &
                          trim(w%word)//' and '//trim(option_words(j)%word)//' differ in word and kind')
            end do
         end associate
         if (allocated(err)) return
      end do
      do id = 1, n_keys
         if (keys(id)%type /= type_word) cycle
         call check(err, count(option_words%key == id) >= 2, trim(keys(id)%name)//' has words')
         call check(err, .not. has_kind(id, 0), trim(keys(id)%name)//': 0 is no kind')
      end do
   end subroutine test_option_words
end module test_input_tables
