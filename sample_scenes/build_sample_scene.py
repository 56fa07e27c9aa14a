"""Build the sample scene: ``python sample_scenes/build_sample_scene.py [FOLDER]`` writes FOLDER/sample_scene.blend
(default: sample_scenes/out). Render it with ``lowcam render FOLDER/sample_scene.blend --frames 1-2 -o out/`` or
``blender -b FOLDER/sample_scene.blend -a`` with the extension enabled."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lowcam_blender import submodule  # noqa: E402

if __name__ == "__main__":
    folder = sys.argv[1] if len(sys.argv) > 1 else str(Path(__file__).resolve().parent / "out")
    print(submodule("addon.sample").build_sample_scene(folder))
