stagectl: stagectl.c stage.h stage_proto.h
stage.h:
stage_proto.h:
