# build-ground: a site's prior map (PCD) -> its ground model (ground.yaml + ground.pgm or .blocks).
$(eval $(call cxx_program,build-ground,tools/build-ground))

# Unit test of the core: built in blocks = one dense grid, corner for corner (tests/test_c_units.py).
$(eval $(call c_test,test_ground_build,tests/c/test_ground_build.c tools/build-ground/ground_build.c))
$(OBJ)/tests/c/test_ground_build.o: CPPFLAGS += -I$(TOP)/tools/build-ground
