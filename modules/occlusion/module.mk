# occlusion: which parts of each agent real objects hide from the eye (core: OctoMap map, pipeline).
$(eval $(call cxx_program,occlusion,modules/occlusion modules/occlusion/core,-loctomap -loctomath))
