"""Where the camera looks: the default camera that frames a whole shot (`framing`), the
course camera, a scene's own camera.

May import: pipeline.physics (collider poses), pipeline.scene, shading.camera.
"""
