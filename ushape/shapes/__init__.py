"""Procedural chairs and tables with exact analytic SDFs and watertight meshes (the data's source).

`generate_shape(category, seed)` returns the same `Shape` for the same arguments on any machine.
A shape is a union of primitives (boxes, rounded boxes, slabs over rounded-rectangle or ellipse
profiles, capped cones/cylinders, capsules, tori), each belonging to a named, coloured part.

Frames. Parts are built in metres, y up, front +Z (ShapeNet's canonical frame), then seen
through DeepSDF's normalisation: normalised = (raw - centre) / scale, centre = bounding-box centre,
scale = 1.03 * largest distance of the surface from the centre, so the surface reaches radius
1/1.03. Every Shape method takes and returns normalised coordinates and distances.

SDF. `Shape.sdf` is the minimum of exact primitive SDFs: exact outside the shape, a lower bound on
the depth inside, exact on the surface. `Shape.mesh(resolution)` runs marching cubes on that SDF
near the surface only; the mesh is watertight with outward normals. No primitive is thinner than
`MIN_THICKNESS` (0.03 normalised: at least 3.8 cells at resolution 256), so legs and slats survive.

Parts (`Shape.part_names`, a subset in this order): chairs: seat, back, arms, legs, apron,
stretchers, column, base, footrest; tables: top, legs, apron, stretchers, shelf, column, base.
Back posts belong to the back; feet, hubs, casters, runners and trestle feet/cleats to the base.

Chair style keys (`Shape.style`; lengths in metres, angles in degrees):
  base: four_legs | pedestal (column on a star with casters or a disc) | sled (closed tube
        loops) | cantilever (tube frame open at the back, floor crossbar)
  back: solid | slatted | open_frame (rails, empty middle) | none (a stool)
  arms: bool;  seat_shape: rectangular | rounded | round;  bar_height: bool (stools only)
  seat_height, seat_width, seat_depth, seat_thickness, seat_corner
  with a back: back_height, back_tilt_deg, back_thickness, back_gap, back_width_frac,
        back_panel_shape (rect | rounded | oval, solid backs), rail_height,
        slat_direction (vertical | horizontal), n_slats, slat_width
  four_legs: leg_profile (square | round | tapered), leg_thickness, leg_splay_deg, stretchers,
        apron, [stretcher_layout (box | H), stretcher_height], [apron_height]
  pedestal: pedestal_foot (star | disc), column_radius, footrest_ring, [star_spokes,
        spoke_length] or [disc_radius]
  sled / cantilever: tube_radius, runner_overhang
  arms: arm_height, arm_width, arm_thickness, arm_support_z
Table style keys:
  size_class: coffee | dining | bar | side;  base: four_legs | pedestal | trestle
  top: rectangular | round | oval (trestles: rectangular or oval); table_height, top_length
        (along x), top_width, top_thickness, top_corner
  four_legs: leg_profile, leg_thickness, leg_splay_deg, leg_inset, apron, shelf, stretchers,
        [apron_height], [shelf_height, shelf_thickness], [stretcher_layout (box | H | X),
        stretcher_height]  (shelves only on coffee and side tables, never with stretchers)
  pedestal: n_pedestals (2 under long tops), column_radius, column_profile (cylinder | flared),
        pedestal_foot (star | disc | cross), foot_spokes, foot_radius, stretchers,
        stretcher_height
  trestle: trestle_upright (board | twin_posts | x_legs), trestle_inset, foot_length,
        member_width, board_width, stretchers, stretcher_height
Both: palette (wood | two_tone_wood | metal_frame | painted | upholstered | white_modern) and
colours ({surface, frame, accent} -> RGB in [0, 1]; each part takes its role's colour).
"""

from ushape.shapes.frame import MIN_THICKNESS, SPHERE_BUFFER
from ushape.shapes.generate import CATEGORIES, generate_shape, sample_style
from ushape.shapes.shape import Part, Shape

__all__ = [
    "CATEGORIES",
    "MIN_THICKNESS",
    "SPHERE_BUFFER",
    "Part",
    "Shape",
    "generate_shape",
    "sample_style",
]
