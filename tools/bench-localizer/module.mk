# bench-localizer: the localizer's scan-to-map registration vs PCL NDT and small_gicp.
$(eval $(call cxx_program,bench-localizer,tools/bench-localizer modules/localizer/core,$(shell pkg-config --libs pcl_registration pcl_kdtree pcl_search 2>/dev/null)))
$(OBJ)/tools/bench-localizer/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core

.PHONY: bench-localizer bench-localizer-real
BENCH_TARGETS += bench-localizer
