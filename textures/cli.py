"""`textures`: generate the paper's textures, check any texture against the design criteria,
export a printable sphere.

Exit status: 0 success (check: every criterion passed), 1 a criterion failed,
2 usage error or unusable input (the message names the file).
"""
import argparse
import json
import os
import sys

from textures import generate

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2


def get_args_parser():
    """The argument parser of the `textures` command."""
    p = argparse.ArgumentParser(
        prog="textures",
        description="Textures for sphere pose estimation (the paper's section 2.1 and 3.3).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    g = sub.add_parser("generate", formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help="write the six paper textures Texture_{1,2,3}_{bw,color}.png",
                       description="Write the six paper textures Texture_{1,2,3}_{bw,color}.png "
                                   "(equirectangular, deterministic) into a folder.")
    g.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    g.add_argument("--height", type=int, default=generate.HEIGHT,
                   help="image height in pixels; the width is twice this")

    c = sub.add_parser("check", formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help="measure a texture against the design criteria",
                       description="Measure an equirectangular texture (width = 2 x height; PNG, JPEG, ...) "
                                   "against the paper's design criteria: stripe spacing ratio, area ratio, "
                                   "CIEDE2000 colour differences, Tamura features and orientation "
                                   "uniqueness over the P1 pose range. Exit 0 when every criterion "
                                   "passes, 1 when one fails, 2 for an unusable file.")
    c.add_argument("file", metavar="FILE", help="texture image")
    c.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    c.add_argument("--step", type=float, default=3.0,
                   help="pose grid step in degrees for the uniqueness scan (P1: 3)")
    c.add_argument("--no-uniqueness", action="store_true", help="skip the uniqueness scan")
    c.add_argument("--no-progress", action="store_true", help="no progress bar")

    e = sub.add_parser("export-sphere", formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       help="write a printable textured sphere (OBJ + MTL + PNG)",
                       description="Write <name>.obj, <name>.mtl and the texture PNG: the renderer's "
                                   "own UV sphere mesh at the given diameter, in millimetres.")
    e.add_argument("--texture", required=True, metavar="PNG", help="equirectangular PNG texture")
    e.add_argument("--diameter", required=True, type=float, metavar="MM",
                   help="sphere diameter in mm (finite, > 0, at most 10000)")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    e.add_argument("--lat-segments", type=int, default=180, help="rings of latitude of the mesh (2..720)")
    e.add_argument("--lon-segments", type=int, default=360, help="segments of longitude of the mesh (3..1440)")
    e.add_argument("--name", default=None,
                   help="base name of the OBJ and MTL, a plain file name written inside --out "
                        "(default: <texture>_sphere)")
    return p


def cmd_generate(args):
    """Write the six textures."""
    if args.height < 32:
        print(f"textures generate: --height {args.height}: at least 32", file=sys.stderr)
        return EXIT_USAGE
    for path in generate.generate_all(args.out, 2 * args.height, args.height):
        print(path)
    return EXIT_OK


def _format_value(ch):
    """Measured value with its unit, '-' when there is none."""
    v, unit = ch["value"], ch["unit"]
    if v is None:
        return "-"
    if unit == ":1":
        return f"{v}:1"
    return f"{v} {unit}" if unit else f"{v}"


def format_table(path, checks, palette):
    """Human-readable report."""
    verdict = {True: "PASS", False: "FAIL", None: "info"}
    rows = [(ch["name"], _format_value(ch), ch["requirement"], verdict[ch["passed"]]) for ch in checks]
    widths = [max(len(r[i]) for r in rows + [("criterion", "measured", "requirement", "result")])
              for i in range(4)]
    line = lambda r: "  ".join(str(x).ljust(w) for x, w in zip(r, widths)).rstrip()
    out = [f"texture: {path}",
           "palette: " + ", ".join(f"#{r:02x}{g:02x}{b:02x} Lab({l:.0f},{a:.0f},{bb:.0f}) {s * 100:.1f}%"
                                   for (r, g, b), (l, a, bb), s in zip(palette.rgb, palette.lab, palette.share))
           + f"; blank #{'%02x%02x%02x' % tuple(palette.rgb[palette.blank])}",
           "", line(("criterion", "measured", "requirement", "result")),
           line(tuple("-" * w for w in widths))]
    out += [line(r) for r in rows]
    out.append("")
    for ch in checks:
        out.append(f"{ch['name']}: {ch['details']}")
    failed = [ch["name"] for ch in checks if ch["passed"] is False]
    out.append("")
    out.append("verdict: " + ("PASS" if not failed else "FAIL (" + ", ".join(failed) + ")"))
    return "\n".join(out)


def cmd_check(args):
    """Check one texture; exit 1 if any criterion fails."""
    from textures.criteria import check_texture
    from textures.textureio import TextureError, load_texture
    if not args.step > 0:
        print(f"textures check: --step {args.step}: must be positive", file=sys.stderr)
        return EXIT_USAGE
    try:
        rgb = load_texture(args.file)
    except TextureError as e:
        print(f"textures check: {e}", file=sys.stderr)
        return EXIT_USAGE
    checks, pal = check_texture(rgb, step=args.step, progress=not args.no_progress,
                                uniqueness=not args.no_uniqueness)
    passed = all(ch["passed"] is not False for ch in checks)
    if args.json:
        doc = {"file": args.file, "width": int(rgb.shape[1]), "height": int(rgb.shape[0]),
               "palette": [{"rgb": [int(v) for v in c], "lab": [round(float(v), 2) for v in l],
                            "share": round(float(s), 4)}
                           for c, l, s in zip(pal.rgb, pal.lab, pal.share)],
               "blank": pal.blank, "criteria": checks, "pass": passed}
        print(json.dumps(doc, indent=1))
    else:
        print(format_table(args.file, checks, pal))
    return EXIT_OK if passed else EXIT_FAIL


def cmd_export(args):
    """Write the printable sphere."""
    from textures.export import ExportError, check_args, export_sphere
    from textures.textureio import TextureError, load_texture
    try:
        check_args(args.diameter, args.lat_segments, args.lon_segments, args.name)
        load_texture(args.texture, require_png=True)
    except (ExportError, TextureError) as e:
        print(f"textures export-sphere: {e}", file=sys.stderr)
        return EXIT_USAGE
    try:
        paths = export_sphere(args.texture, args.diameter, args.out,
                              args.lat_segments, args.lon_segments, args.name)
    except ExportError as e:
        print(f"textures export-sphere: {e}", file=sys.stderr)
        return EXIT_USAGE
    for path in paths:
        print(path)
    return EXIT_OK


def main(argv=None):
    """Entry point of the `textures` console command."""
    args = get_args_parser().parse_args(argv)
    try:
        return {"generate": cmd_generate, "check": cmd_check, "export-sphere": cmd_export}[args.command](args)
    except OSError as e:
        print(f"textures {args.command}: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
