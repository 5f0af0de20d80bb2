# build-ground: a site's prior map (PCD) -> its ground model (ground.yaml + ground.pgm).
$(eval $(call cxx_program,build-ground,tools/build-ground))
