# director: scenario runtime (core/ is pure: scenario loader, geometry, runtime; main.c the shell).
$(eval $(call c_program,director,modules/director modules/director/core,-lccd))
# Unit test of the core (C, linked through cxx_test for its extra-libs argument).
$(eval $(call cxx_test,test_director,tests/c/test_director.c $(call dir_c,modules/director/core),-lccd))
