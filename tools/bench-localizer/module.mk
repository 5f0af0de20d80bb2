# bench-localizer: the localizer's scan-to-map registration vs PCL NDT and small_gicp.
$(eval $(call cxx_program,bench-localizer,tools/bench-localizer modules/localizer/core,$(shell pkg-config --libs pcl_registration pcl_kdtree pcl_search 2>/dev/null)))
$(OBJ)/tools/bench-localizer/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

.PHONY: bench-localizer bench-localizer-real
BENCH_TARGETS += bench-localizer

# Unit tests of the registration core (run by make test through tests/test_c_units.py).
LOCREG_CORE := modules/localizer/core/registration.cpp modules/localizer/core/regmap.cpp modules/localizer/core/deskew.cpp
$(eval $(call cxx_test,test_registration,tests/c/test_registration.cpp $(LOCREG_CORE)))
$(OBJ)/tests/c/test_registration.o: CPPFLAGS += -I$(TOP)/modules/localizer/core
