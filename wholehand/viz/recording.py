"""An offline meshcat window: records the scene's commands and writes one self-contained HTML."""

from __future__ import annotations

import base64
from typing import Any

import umsgpack
from meshcat.servers.tree import SceneTree, find_node, walk


class RecordingWindow:
    """A meshcat window without a server: keeps the scene tree to write standalone HTML.

    It stands in for :class:`meshcat.visualizer.ViewerWindow` (``send`` and ``get_scene``), so a
    :class:`meshcat.Visualizer` built on it records commands instead of sending them; the HTML
    embeds meshcat's packaged viewer JavaScript and opens offline from a file.
    """

    web_url: str | None = None

    def __init__(self) -> None:
        self.tree = SceneTree()

    def send(self, command: Any) -> None:
        data = command.lower()
        path = [p for p in data["path"].split("/") if p]
        packed = umsgpack.packb(data)
        kind = data["type"]
        node = find_node(self.tree, path)
        if kind == "set_transform":
            node.transform = packed
        elif kind == "set_object":
            node.object = packed
            node.properties = []
        elif kind == "set_property":
            node.properties.append(packed)
        elif kind == "set_animation":
            node.animation = packed
        elif kind == "delete":
            if path:
                find_node(self.tree, path[:-1]).pop(path[-1], None)
            else:
                self.tree = SceneTree()

    def get_scene(self, overlay_html: str = "", title: str = "wholehand") -> str:
        """Standalone HTML of the scene (viewer JS inlined; data as base64 msgpack).

        Unlike meshcat's own ``static_html`` (one asynchronous ``fetch`` per command, resolved
        in any order), the commands are decoded and run synchronously in tree order, parents
        first, with animations last, so every node exists before the animation binds to it.
        """
        import meshcat.servers.zmqserver as zs

        scene, animations = [], []
        for node in walk(self.tree):
            for packed in [node.object, *node.properties, node.transform]:
                if packed is not None:
                    scene.append(packed)
            if node.animation is not None:
                animations.append(node.animation)
        blobs = ",\n".join(f'"{base64.b64encode(b).decode("ascii")}"' for b in scene + animations)
        with open(f"{zs.VIEWER_ROOT}/main.min.js", encoding="utf-8") as f:
            viewer_js = f.read()
        return _HTML.format(title=title, viewer_js=viewer_js, commands=blobs, overlay=overlay_html)

    def open(self) -> RecordingWindow:
        return self

    def close(self) -> None:
        pass


_HTML = """<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{title}</title>
<style>body {{margin: 0;}} #meshcat-pane {{width: 100vw; height: 100vh; overflow: hidden;}}
#wholehand-overlay {{position: fixed; left: 8px; bottom: 8px; pointer-events: none;
 font: 12px sans-serif; background: rgba(255,255,255,0.85);}}</style></head>
<body>
<div id="meshcat-pane"></div>
<script>
{viewer_js}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
var commands = [
{commands}
];
for (const b64 of commands) {{
  const bin = atob(b64);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  viewer.handle_command_bytearray(bytes);
}}
</script>
{overlay}
</body>
</html>
"""
