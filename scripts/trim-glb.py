#!/usr/bin/env python3
"""Writes a copy of a GLB that keeps only the named animation clips.

    scripts/trim-glb.py IN.glb OUT.glb CLIP [CLIP ...]

Accessors and buffer views that only the dropped clips used go too, and the binary chunk
is repacked (4-byte aligned); everything else (nodes, meshes, skins, materials, images)
is kept as it is. Used to ship the KayKit Knight with the clips its teacher plays: its 76
clips are 90 % of the file (assets/knight/README.md).
"""

import json
import struct
import sys


def read_glb(path):
    data = open(path, "rb").read()
    magic, version, _ = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2:
        sys.exit(f"{path}: not a glTF 2.0 binary file")
    offset, doc, binary = 12, None, b""
    while offset < len(data):
        length, kind = struct.unpack_from("<I4s", data, offset)
        chunk = data[offset + 8 : offset + 8 + length]
        if kind == b"JSON":
            doc = json.loads(chunk)
        elif kind == b"BIN\x00":
            binary = chunk
        offset += 8 + length
    if doc is None:
        sys.exit(f"{path}: no JSON chunk")
    return doc, binary


def accessors_used(doc):
    used = set()
    for mesh in doc.get("meshes", []):
        for primitive in mesh["primitives"]:
            used.update(primitive["attributes"].values())
            if "indices" in primitive:
                used.add(primitive["indices"])
            for target in primitive.get("targets", []):
                used.update(target.values())
    for skin in doc.get("skins", []):
        if "inverseBindMatrices" in skin:
            used.add(skin["inverseBindMatrices"])
    for animation in doc.get("animations", []):
        for sampler in animation["samplers"]:
            used.update((sampler["input"], sampler["output"]))
    return used


def remap_accessors(doc, new_index):
    for mesh in doc.get("meshes", []):
        for primitive in mesh["primitives"]:
            primitive["attributes"] = {k: new_index[v] for k, v in primitive["attributes"].items()}
            if "indices" in primitive:
                primitive["indices"] = new_index[primitive["indices"]]
            if "targets" in primitive:
                primitive["targets"] = [
                    {k: new_index[v] for k, v in t.items()} for t in primitive["targets"]
                ]
    for skin in doc.get("skins", []):
        if "inverseBindMatrices" in skin:
            skin["inverseBindMatrices"] = new_index[skin["inverseBindMatrices"]]
    for animation in doc.get("animations", []):
        for sampler in animation["samplers"]:
            sampler["input"] = new_index[sampler["input"]]
            sampler["output"] = new_index[sampler["output"]]


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__.strip().splitlines()[2].strip())
    source, target, keep = sys.argv[1], sys.argv[2], sys.argv[3:]
    doc, binary = read_glb(source)
    names = [a.get("name") for a in doc.get("animations", [])]
    missing = [k for k in keep if k not in names]
    if missing:
        sys.exit(f"{source}: no clip named {', '.join(missing)}")
    doc["animations"] = [a for a in doc["animations"] if a.get("name") in keep]
    if any("sparse" in a for a in doc.get("accessors", [])):
        sys.exit(f"{source}: sparse accessors are not supported")
    used = sorted(accessors_used(doc))
    new_accessor = {old: new for new, old in enumerate(used)}
    doc["accessors"] = [doc["accessors"][i] for i in used]
    remap_accessors(doc, new_accessor)
    views = sorted(
        {a["bufferView"] for a in doc["accessors"] if "bufferView" in a}
        | {i["bufferView"] for i in doc.get("images", []) if "bufferView" in i}
    )
    new_view = {old: new for new, old in enumerate(views)}
    packed = bytearray()
    kept_views = []
    for old in views:
        view = dict(doc["bufferViews"][old])
        if view.get("buffer", 0) != 0:
            sys.exit(f"{source}: only the GLB's own buffer is supported")
        start = view.get("byteOffset", 0)
        chunk = binary[start : start + view["byteLength"]]
        packed.extend(b"\0" * (-len(packed) % 4))
        view["byteOffset"] = len(packed)
        packed.extend(chunk)
        kept_views.append(view)
    doc["bufferViews"] = kept_views
    for accessor in doc["accessors"]:
        if "bufferView" in accessor:
            accessor["bufferView"] = new_view[accessor["bufferView"]]
    for image in doc.get("images", []):
        if "bufferView" in image:
            image["bufferView"] = new_view[image["bufferView"]]
    packed.extend(b"\0" * (-len(packed) % 4))
    doc["buffers"] = [{"byteLength": len(packed)}]
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(packed)
    with open(target, "wb") as out:
        out.write(struct.pack("<4sII", b"glTF", 2, total))
        out.write(struct.pack("<I4s", len(text), b"JSON") + text)
        out.write(struct.pack("<I4s", len(packed), b"BIN\x00") + bytes(packed))
    print(f"{target}: {len(doc['animations'])} clips, {total} bytes (was {len(open(source, 'rb').read())})")


if __name__ == "__main__":
    main()
