"""``uav-landing check-renderer``: the renderer's self-test (``render.selftest``) on this machine."""


def register(sub) -> None:
    p = sub.add_parser("check-renderer", help="draw the shipped reference poses and compare them with the reference")
    p.add_argument("--reference", help="a reference .npz (default: the shipped models/render_reference.npz)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from .context import gl_context
    from .selftest import check_renderer

    print(f"GL_RENDERER: {gl_context().info['GL_RENDERER']}")
    print(f"renderer self-test {check_renderer(args.reference).summary}")
    return 0
