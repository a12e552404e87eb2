"""Semantic classes of the procedural rooms: names, ids and display colours.

The id is the value stored in class maps (uint8). Names are plain words on purpose: the
training part embeds each class by the CLIP text encoder's embedding of its name, and
``spar render --labels`` takes the same names.
"""

CLASS_NAMES = ("wall", "floor", "ceiling", "sofa", "table", "window", "door", "plant",
               "person", "pet")
CLASS_ID = {name: i for i, name in enumerate(CLASS_NAMES)}
# The distractors: what moves between frames and what the motion mask marks.
DYNAMIC_CLASSES = ("person", "pet")

# Palette of the class PNGs (palette-indexed, so a viewer shows colours while the stored
# value stays the id).
PALETTE = (
    (174, 199, 232),  # wall
    (152, 223, 138),  # floor
    (220, 220, 220),  # ceiling
    (214, 39, 40),    # sofa
    (255, 127, 14),   # table
    (31, 119, 180),   # window
    (140, 86, 75),    # door
    (44, 160, 44),    # plant
    (227, 119, 194),  # person
    (188, 189, 34),   # pet
)


def classes_json():
    """The list written as classes.json and into scene.json."""
    return [{"id": i, "name": n, "color": list(PALETTE[i]), "dynamic": n in DYNAMIC_CLASSES}
            for i, n in enumerate(CLASS_NAMES)]
