"""
Compiling gymnasium's MuJoCo models without mujoco's deprecation warnings.

gymnasium's ``half_cheetah.xml`` scales its masses with the compiler attribute ``settotalmass``, which recent mujoco
releases deprecate: each compile then logs a warning, and mujoco's default logger appends it to ``MUJOCO_LOG.TXT`` in
the current folder, once per env made. :func:`compile_model` compiles the same file without the attribute and scales
the masses afterwards with ``mj_setTotalmass`` and ``mj_setConst``, as mujoco's message advises: the compiled model is
the same (masses, inertias and the constants derived from them are equal, and so are trajectories).
"""

import re

import mujoco

#: ``settotalmass="<value>"`` in a ``<compiler>`` element
_SETTOTALMASS = re.compile(r'\s+settotalmass\s*=\s*"([^"]*)"')


def compile_model(path: str, offwidth: int = 0, offheight: int = 0) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """
    Compile an MJCF file as gymnasium's ``MujocoEnv._initialize_simulation`` does, without deprecated attributes.

    :param path: The XML file
    :param offwidth: Smallest width of the off-screen framebuffer (gymnasium grows it to the render width)
    :param offheight: Smallest height of the off-screen framebuffer
    :return: The model and its data
    """
    with open(path) as file:
        xml = file.read()
    match = _SETTOTALMASS.search(xml)
    # A file that refers to others (meshes, includes) is compiled from its path, where those resolve
    if match is None or "file=" in xml:
        model = mujoco.MjModel.from_xml_path(path)
    else:
        model = mujoco.MjModel.from_xml_string(_SETTOTALMASS.sub("", xml, count=1))
        mujoco.mj_setTotalmass(model, float(match.group(1)))
        mujoco.mj_setConst(model, mujoco.MjData(model))
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, offwidth)
    model.vis.global_.offheight = max(model.vis.global_.offheight, offheight)
    return model, mujoco.MjData(model)
