# refine-poses: multi-scan refinement of a LiDAR sequence's poses (core: modules/localizer/core/refine).
$(eval $(call cxx_program,refine-poses,tools/refine-poses modules/localizer/core))
$(OBJ)/tools/refine-poses/%.o: CPPFLAGS += -I$(TOP)/modules/localizer/core
