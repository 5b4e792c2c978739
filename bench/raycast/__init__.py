"""An independent ray-caster of the textured sphere, for evaluation frames.

Written from docs/conventions.md and the camera file of docs/interfaces.md
with numpy and OpenCV only; it imports nothing of sim/ or training/, so a
model's accuracy on its frames is not a fit to the training renderer.
Modules: camera (camera file, rays, lens), shapes (ray-solid hits),
backgrounds, mounts, render (rays, texture, shading, camera effects),
families (what each evaluation family draws), frames (a folder of frames and
truth.jsonl). Command line: `python bench/raycast --help`.
"""
