import os
from glob import glob

from setuptools import find_packages, setup

package_name = "pvo_pseudosensors"


def model_files() -> list[tuple[str, list[str]]]:
    """Every shipped model directory under models/, nested ones too (an ensemble's members), as data_files."""
    return [
        (os.path.join("share", package_name, root), sorted(os.path.join(root, name) for name in files))
        for root, _, files in sorted(os.walk("models"))
        if files
    ]


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        *model_files(),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pvo maintainers",
    maintainer_email="maintainers@pvo-project.org",
    description="Pseudo-sensors of pvo: the learning harness, Sun-BCNN, the simulated sun HydraNet, DPC-Net",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "simulated_sun = pvo_pseudosensors.simulated_sun_node:main",
            "sun_bcnn = pvo_pseudosensors.sun_bcnn_node:main",
            "hydranet = pvo_pseudosensors.hydranet_node:main",
            "dpc_net = pvo_pseudosensors.dpc_net_node:main",
        ]
    },
)
