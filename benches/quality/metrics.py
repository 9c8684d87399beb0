"""MSE (RGB in [0, 1]) and GMSD of rendered images against their input, for bench.sh and rd.sh.

GMSD follows the authors' GMSD.m on Octave's rgb2gray luma (0-255), as covec::perceptual::gmsd
does; `metrics.py --check FIXTURES` verifies it against the Octave values that
tests/pipeline/perceptual_reference.rs holds. Usage: metrics.py [--skin MASK.png] REF.png RENDER.png...
(one "mse gmsd" line per render). With a skin mask (white: skin; `covec eval --faces FILE
--write-masks DIR` writes them) two more numbers, as `covec eval --faces` scores skin: the
CIEDE2000 between the mean skin colours (means in CIELAB) and the mean per-pixel CIEDE2000
inside the mask (needs scikit-image)."""
import sys, numpy as np
from PIL import Image
def flat(p):
    im = Image.open(p).convert("RGBA"); bg = Image.new("RGBA", im.size, (255,255,255,255)); bg.alpha_composite(im)
    return np.asarray(bg.convert("RGB"), dtype=np.float64) / 255
def luma(rgb): return rgb @ np.array([0.298936, 0.587043, 0.114021]) * 255
def conv_same_zero(a, k):
    # MATLAB conv2(a, k, 'same') for a 3x3 kernel
    p = np.pad(a, 1); out = np.zeros_like(a); kf = k[::-1, ::-1]
    for i in range(3):
        for j in range(3):
            out += kf[i, j] * p[i:i+a.shape[0], j:j+a.shape[1]]
    return out
def gmsd(ref, dist):
    out = []
    for y in (luma(ref), luma(dist)):
        p = np.pad(y, ((0,1),(0,1)))
        avg = (p[:-1,:-1] + p[1:,:-1] + p[:-1,1:] + p[1:,1:]) / 4
        y = avg[::2, ::2]
        dx = np.array([[1,0,-1]]*3)/3.0
        gx = conv_same_zero(y, dx); gy = conv_same_zero(y, dx.T)
        out.append(np.sqrt(gx*gx + gy*gy))
    g1, g2 = out; T = 170.0
    q = (2*g1*g2 + T) / (g1*g1 + g2*g2 + T)
    return q.std(ddof=1)
def skin(ref, dist, mask):
    from skimage.color import deltaE_ciede2000, rgb2lab
    a, b = rgb2lab(dist)[mask], rgb2lab(ref)[mask]
    return deltaE_ciede2000(a.mean(0), b.mean(0)), deltaE_ciede2000(a, b).mean()
if __name__ == "__main__":
    if sys.argv[1] == "--check":
        d = sys.argv[2]
        g = gmsd(flat(f"{d}/hopper_ref.png"), flat(f"{d}/hopper_vector.png"))
        assert abs(g - 0.2404116720) < 1e-6, g
        sys.exit(0)
    args, mask = sys.argv[1:], None
    if args[0] == "--skin":
        mask = np.asarray(Image.open(args[1]).convert("L")) > 127; args = args[2:]
    ref = flat(args[0])
    for png in args[1:]:
        d = flat(png)
        extra = " %.4f %.4f" % skin(ref, d, mask) if mask is not None else ""
        print(f"{((d-ref)**2).mean():.6f} {gmsd(ref, d):.6f}{extra}")
