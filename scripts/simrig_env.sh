# The simulated rig's model, scene and camera file: sourced by simrig.sh and
# demo.sh, so that the demo checks its frames against what the rig ran with.
# The environment overrides each (simrig.sh --help).
MODEL=${MODEL:-training/models/Texture_3_color.onnx}
SCENE=${SCENE-sim/scenes/rig.json}
CAMERA_FILE=${CAMERA_FILE-sim/scenes/rig_camera.json}
[ -n "$SCENE" ] || CAMERA_FILE="" # plain renders have no lens and no rig camera
