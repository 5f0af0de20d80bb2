# localizer: LiDAR localization in the prior map (core: filter, pipeline, registration).
$(eval $(call cxx_program,localizer,modules/localizer modules/localizer/core))
