"""`scene-recon graph SOURCE`: build the contact graph of a scene and show it."""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

from scene_recon.commands.common import add_preset_option, preset_from_args, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "graph",
        help="build the contact graph (supports, proximal relations, boxes) of a scene",
        description="Build the contact graph (paper Sec. 2) of a ground-truth folder (*_groundtruth/ with "
        "scene.json: complete meshes, the paper's cg_map setting) or of a mapped-scene folder (entities.json + "
        "meshes/<id>.ply, see recon_core/entity.py). Prints the parse tree (class, support score, joint) and "
        "writes contact_graph.json and contact_graph.png (top-down boxes + tree) into --out.",
    )
    p.add_argument("source", help="ground-truth folder (scene.json) or mapped-scene folder (entities.json)")
    p.add_argument("--out", help="output folder (default: out/graph/<scene name>)")
    p.add_argument("--config", metavar="YAML", help="builder config (default: config/scene_graph.yaml)")
    p.add_argument("--joints", metavar="YAML", help="support-joint table (default: config/support_joints.yaml)")
    p.add_argument("--observed", metavar="BAG",
                   help="ground-truth source only: keep only the mesh faces this recording's camera saw")
    p.add_argument("--contact-band", type=float, default=0.0, metavar="M",
                   help="with --observed: cut this height above each object's support (TSDF contact fusion)")
    p.add_argument("--urdf", action="store_true", help="also write the kinematic tree as URDF under OUT/urdf/")
    p.add_argument("--no-picture", action="store_true", help="do not draw contact_graph.png")
    p.add_argument("--json", action="store_true", help="print the graph summary as JSON instead of the tree")
    add_preset_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from recon_core.config import preset_overrides
    from recon_core.entity import save_entities
    from recon_core.errors import InputError
    from scene_graph.builder import ContactGraphBuilder
    from scene_graph.config import load_scene_graph_config
    from scene_graph.joints import load_support_joints
    from scene_recon.sources import load_source

    cfg = load_scene_graph_config(args.config, preset_overrides(preset_from_args(args), "scene_graph"))
    joints = load_support_joints(args.joints or cfg.support_joints or None)
    try:
        source = load_source(args.source)
    except InputError as exc:
        raise FileNotFoundError(str(exc)) from exc
    entities = source.entities
    observed = None
    if args.observed:
        if source.kind != "ground_truth":
            raise FileNotFoundError("--observed needs a ground-truth source (scene.json)")
        from scene_recon.evaluation.observed import ObservationConfig, camera_views, observed_entities
        from scene_recon.synthetic.scene import GroundTruthScene

        scene = GroundTruthScene.load(source.path)
        obs_cfg = ObservationConfig(contact_band=args.contact_band)
        entities, observed = observed_entities(scene, camera_views(args.observed, obs_cfg), obs_cfg)
    builder = ContactGraphBuilder(cfg, joints)
    t0 = time.perf_counter()
    builder.update(entities)
    t1 = time.perf_counter()
    graph = builder.build(name=source.name, frame_id=source.frame_id)
    graph.stats["features_s"] = t1 - t0
    graph.stats["total_s"] = time.perf_counter() - t0
    if observed is not None:
        graph.stats["observed_area_share"] = observed
    from scene_recon.commands.scene_identity import ground_truth_identity, map_identity

    scene_id = ground_truth_identity(source.path) if source.kind == "ground_truth" else map_identity(source.path)
    if scene_id:  # the generated scene behind the graph: eval-graph / eval-scene refuse another one's ground truth
        graph.stats["scene"] = scene_id
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", source.name) or "scene"
    out = Path(args.out) if args.out else Path("out") / "graph" / safe
    out.mkdir(parents=True, exist_ok=True)
    graph_path = graph.save(out / "contact_graph.json")
    # the geometry behind every node (split walls, merged objects): what CAD replacement aligns to
    node_dir = save_entities(list(builder.node_entities().values()), out / "nodes", graph.frame_id,
                             graph.name).parent
    files = {"graph": str(graph_path), "node_entities": str(node_dir)}
    if not args.no_picture:
        from scene_graph.draw import draw_graph

        files["picture"] = str(draw_graph(graph, out / "contact_graph.png"))
    if args.urdf:
        from scene_graph.kinematic import to_kinematic_tree

        tree = to_kinematic_tree(graph, builder.node_entities(), joints.object_mass)  # split walls included
        files["urdf"] = str(tree.to_urdf(out / "urdf", filename="scene.urdf"))
    if args.json:
        print_json({"source": str(source.path), "kind": source.kind, "name": source.name,
                    "nodes": len(graph.nodes) - 1, "support_edges": len(graph.supports),
                    "proximal_edges": len(graph.proximal), "skipped": graph.skipped, "files": files,
                    "stats": {k: v for k, v in graph.stats.items() if k != "observed_area_share"}})
        return 0
    print(graph.format_tree())
    print(f"{len(graph.nodes) - 1} nodes, {len(graph.proximal)} proximal relations, built in "
          f"{graph.stats.get('total_s', 0.0):.2f} s")
    for kind, path in files.items():
        print(f"{kind}: {path}")
    return 0
