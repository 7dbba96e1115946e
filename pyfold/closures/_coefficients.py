"""Published coefficient tables of the fitted closures (numbers only; formulas live in
the closure modules). Each table cites the paper it comes from; the digits were
cross-checked against two independent public implementations (fiberoripy,
github.com/meyer-nils/fiberoripy, ``closures.py``; SFRPMicroMechanics.jl,
github.com/barabule/SFRPMicroMechanics, ``src/closures.jl``) and, for ORL, against the
table reprinted in Kennedy & Zheng, *Injection Molding* (Springer 2009), eq. 5.21.
ORS and ORE were cross-checked against Tucker's MATLAB toolbox (companion to
*Fundamentals of Fiber Orientation*, Hanser 2022; github.com/charlestucker3/
Fiber-Orientation-Tools, ``closeA4.m``) and a second implementation each:
SFRPMicroMechanics.jl (ORS) and fiberpy (github.com/tianyikillua/fiberpy,
``fiberpy/closure.py``, which quotes VerWeyst's thesis, p. 47) for ORE.

Not provided: the 3-D natural closures NAT1 (Verleye & Dupret 1993) and NAT2 (Dupret
& Verleye 1999). Their fitted coefficient tables (reprinted in Chung & Kwon 2001,
Polym. Compos. 22:636) were not found in any source available to us, and the
closures are not reconstructed from memory; ORE below is the orthotropic fit to the
same target (the natural/exact closure of Jeffery's equation).
"""
from __future__ import annotations

# Orthotropic fitted closures: principal values A_11 = A_1111, A_22 = A_2222,
# A_33 = A_3333 as polynomials in the two largest eigenvalues (a1 >= a2 >= a3) of a2:
#   A_mm = C[m][0] + C[m][1] a1 + C[m][2] a1^2 + C[m][3] a2 + C[m][4] a2^2 + C[m][5] a1 a2
# (ORF, ORL, ORW), and for ORW3 the cubic basis
#   1, a1, a1^2, a2, a2^2, a1 a2, a1^2 a2, a1 a2^2, a1^3, a2^3.

#: ORF: Cintra & Tucker (1995), J. Rheol. 39(6):1095-1122, fitted to Folgar-Tucker solutions.
ORF = (
    (0.060964, 0.371243, 0.555301, -0.369160, 0.318266, 0.371218),
    (0.124711, -0.389402, 0.258844, 0.086169, 0.796080, 0.544992),
    (1.228982, -2.054116, 0.821548, -2.260574, 1.053907, 1.819756),
)

#: ORL: Cintra & Tucker (1995), J. Rheol. 39(6):1095, the low-interaction fit.
ORL = (
    (0.104753, 0.346874, 0.544970, -0.563168, 0.471144, 0.491202),
    (0.162210, -0.451257, 0.286639, -0.028702, 0.864008, 0.652712),
    (1.288896, -2.187810, 0.899635, -2.402857, 1.133547, 1.975826),
)

#: ORW: Chung & Kwon (2001), Polym. Compos. 22(5):636-649 (wide interaction range).
#: The a2^2 coefficient of A_11 is 0.333693 in fiberoripy and 0.333692 in
#: SFRPMicroMechanics.jl; the 1e-6 difference is immaterial, fiberoripy's is used.
ORW = (
    (0.070055, 0.339376, 0.590331, -0.396796, 0.333693, 0.411944),
    (0.115177, -0.368267, 0.252880, 0.094820, 0.800181, 0.535224),
    (1.249811, -2.148297, 0.898521, -2.290157, 1.044147, 1.934914),
)

#: ORW3: Chung & Kwon (2001), Polym. Compos. 22(5):636-649, third-order fit.
ORW3 = (
    (-0.1480648093, 0.8084618453, 0.3722003446, 0.7765597096, -1.3431772379,
     -1.7366749542, 0.8895946393, 1.7367571741, -0.0324756095, 0.6631716575),
    (-0.2106349673, 0.9092350296, -1.2840654776, 1.1104441966, 0.1260059291,
     -2.5375632310, 1.9988098293, 1.4863151577, 0.5856304774, -0.0756740034),
    (0.4868019601, 0.5776328438, -2.2462007509, 0.4605743789, -1.9088154281,
     -4.8900459209, 4.0544348937, 3.8542602127, 1.1817992322, 0.9512305286),
)

#: ORS, the "smooth" orthotropic closure: Cintra & Tucker (1995), J. Rheol. 39(6):1095.
#: Linear in (1, a1, a2): A_mm = C[m][0] + C[m][1] a1 + C[m][2] a2. Tucker's toolbox
#: also lists A_44 = A_55 = 0.2 (1 - a1 - a2), A_66 = -0.05 + 0.05 a1 + 0.30 a2; those
#: are exactly what the trace identity gives from these three rows (checked in the tests).
ORS = (
    (-0.15, 1.15, -0.10),
    (-0.15, 0.15, 0.90),
    (0.60, -0.60, -0.60),
)

#: ORE, orthotropic fit to the natural (exact) closure of Jeffery's equation:
#: VerWeyst (1998), PhD thesis, University of Illinois at Urbana-Champaign, p. 47
#: ("ORE" in VerWeyst et al. 1999 and Tucker 2022; "ORN" in Tucker's toolbox).
#: Quartic in the two largest eigenvalues, monomial order
#:   1, a1, a2, a1 a2, a1^2, a2^2, a1^2 a2, a1 a2^2, a1^3, a2^3, a1^2 a2^2, a1^3 a2,
#:   a1 a2^3, a1^4, a2^4.
ORE = (
    (0.636256796880687, -1.872662963738140, -4.479708731937380, 11.958956233232000,
     3.844596924200860, 11.342092427815900, -10.958262606969100, -20.727799468413200,
     -2.116232144710040, -12.387563285561900, 9.815983897167480, 3.479015105674390,
     11.749291117702600, 0.508041387366637, 4.883665977714890),
    (0.636256796880687, -3.315272297421460, -3.037099398254060, 11.827328596885200,
     6.881539520580440, 8.436777467783250, -15.912066715764100, -15.151587260630700,
     -6.487289336419260, -8.638914192840160, 9.325203434526610, 7.746837517132950,
     7.481468706244410, 2.284765316379580, 3.597722511342540),
    (2.740532895602530, -9.121965097826920, -12.257058703625400, 34.319901891698700,
     13.829469912194000, 25.868475525388400, -37.702911802938400, -50.275643192748500,
     -10.880176113317400, -26.963691523971600, 27.334679805448800, 15.265068614865100,
     26.113491400537500, 3.432138403347790, 10.611741806606000),
)

# IBOF: Chung & Kwon (2002), J. Rheol. 46(1):169-194, 5th-order polynomials in the
# invariants II, III for beta_3, beta_4, beta_6 (21 coefficients each, 63 in all),
# in the monomial order
#   1, II, II^2, III, III^2, II III, II^2 III, II III^2, II^3, III^3, II^3 III,
#   II^2 III^2, II III^3, II^4, III^4, II^4 III, II^3 III^2, II^2 III^3, II III^4,
#   II^5, III^5.
IBOF_MONOMIALS = (
    (0, 0), (1, 0), (2, 0), (0, 1), (0, 2), (1, 1), (2, 1), (1, 2), (3, 0), (0, 3),
    (3, 1), (2, 2), (1, 3), (4, 0), (0, 4), (4, 1), (3, 2), (2, 3), (1, 4), (5, 0), (0, 5),
)

IBOF_BETA3 = (
    0.24940908165786e2, -0.435101153160329e3, 0.372389335663877e4, 0.703443657916476e4,
    0.823995187366106e6, -0.133931929894245e6, 0.880683515327916e6, -0.991630690741981e7,
    -0.159392396237307e5, 0.800970026849796e7, -0.237010458689252e7, 0.379010599355267e8,
    -0.337010820273821e8, 0.322219416256417e5, -0.257258805870567e9, 0.214419090344474e7,
    -0.449275591851490e8, -0.213133920223355e8, 0.157076702372204e10, -0.232153488525298e5,
    -0.395769398304473e10,
)

IBOF_BETA4 = (
    -0.497217790110754e0, 0.234980797511405e2, -0.391044251397838e3, 0.153965820593506e3,
    0.152772950743819e6, -0.213755248785646e4, -0.400138947092812e4, -0.185949305922308e7,
    0.296004865275814e4, 0.247717810054366e7, 0.101013983339062e6, 0.732341494213578e7,
    -0.147919027644202e8, -0.104092072189767e5, -0.635149929624336e8, -0.247435106210237e6,
    -0.902980378929272e7, 0.724969796807399e7, 0.487093452892595e9, 0.138088690964946e5,
    -0.160162178614234e10,
)

IBOF_BETA6 = (
    0.234146291570999e2, -0.412048043372534e3, 0.319553200392089e4, 0.573259594331015e4,
    -0.485212803064813e5, -0.605006113515592e5, -0.477173740017567e5, 0.599066486689836e7,
    -0.110656935176569e5, -0.460543580680696e8, 0.203042960322874e7, -0.556606156734835e8,
    0.567424911007837e9, 0.128967058686204e5, -0.152752854956514e10, -0.499321746092534e7,
    0.132124828143333e9, -0.162359994620983e10, 0.792526849882218e10, 0.466767581292985e4,
    -0.128050778279459e11,
)
